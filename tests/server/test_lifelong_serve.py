"""Lifelong mode over real websockets on 127.0.0.1: a gateway running a warehouse shift and a
simulated fleet (turning robots); the trace is checked by the independent checker. In virtual
time (the planner charged 120 ms a call): what is checked does not depend on the machine's
load (in real time a loaded machine finished fewer tasks in the same plan time)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from gateway.server.clock import VirtualClock, run_virtual
from gateway.server.config import GatewayConfig, LifelongSettings
from gateway.server.gateway import Gateway
from sim_clients.connect import websocket_connector
from sim_clients.fleet import SimFleet
from sim_clients.shift import ShiftStats, run_shift
from tracecheck import check_trace, read_trace

ROBOTS = 10


def _shift(tmp_path: Path, plan_ms: float, **lifelong: Any
           ) -> tuple[ShiftStats, Gateway, str]:
    trace = tmp_path / "trace.jsonl"
    out: dict[str, Any] = {}

    async def main() -> None:
        config = GatewayConfig(
            port=0, map=None, autostart=True, speed=10.0, trace=trace, log_level="WARNING",
            lifelong=LifelongSettings(robots=ROBOTS, warehouse=(2, 3), **lifelong))
        async with Gateway(config, clock=VirtualClock(solver_time=120.0)) as gw:
            port = await gw.listen()
            fleet = SimFleet(websocket_connector(f"ws://127.0.0.1:{port}/ws"), range(ROBOTS),
                             clock=gw.clock, send_state=False, duration_jitter=0.2)
            out["stats"] = await run_shift(gw, fleet, plan_ms)
            out["errors"] = list(fleet.stats.errors)
            out["gw"] = gw
            out["metrics"] = gw.metrics.render().decode()

    run_virtual(main())
    assert out["errors"] == []
    return out["stats"], out["gw"], out["metrics"]


def test_a_shift_over_websockets_finishes_tasks_safely(tmp_path: Path) -> None:
    stats, gw, metrics = _shift(tmp_path, 40_000.0)
    assert stats.finished_tasks >= 5
    assert stats.lost == 0 and stats.duplicated == 0 and stats.collisions == 0
    records = read_trace(tmp_path / "trace.jsonl")
    report = check_trace(records)
    assert report.errors == [] and report.collisions == []
    finishes = [(r["robot"], r["action"]) for r in records if r["type"] == "finish"]
    dispatches = [(r["robot"], r["action"]) for r in records if r["type"] == "dispatch"]
    assert len(finishes) == len(set(finishes)) == len(dispatches) == stats.dispatched
    # segments were appended while robots were in the middle of an action
    running: set[int] = set()
    joined = 0
    for r in records:
        if r["type"] == "start":
            running.add(r["robot"])
        elif r["type"] == "finish":
            running.discard(r["robot"])
        elif r["type"] == "segment" and running:
            joined += 1
    assert joined >= 10
    assert any(r["type"] == "start" and r["robot"] >= 0 for r in records)
    turns = sum(1 for r in records if r["type"] == "segment"
                for a in r["agents"] for p, q in zip(a["path"], a["path"][1:], strict=False)
                if p[:2] == q[:2] and p[2] != q[2])
    assert turns > 0  # turning actions ran
    run = gw.engine.lifelong
    assert run is not None and gw.engine.current_run.tasks is run.tasks
    # /metrics: the tasks' assignment waits (p50, p90, p99, max) in seconds
    waits = [float(line.rsplit(" ", 1)[1]) for q in ("0.5", "0.9", "0.99", "1")
             for line in metrics.splitlines()
             if line.startswith(f'fleetgate_task_assignment_wait_seconds{{quantile="{q}"}}')]
    assert len(waits) == 4 and waits == sorted(waits) and waits[3] > 0
