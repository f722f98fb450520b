"""A lifelong shift survives SIGKILL: ``fleetgate serve`` (its own process) runs a warehouse shift
of simulated robots over real websockets, is killed with SIGKILL twice mid-shift (robots
running actions, a planner call possibly outstanding) and restarted with the same command
line; the robots reconnect by themselves and the SAME shift goes on. The independent checker
(tracecheck) reads the one trace file the three processes appended to."""

from __future__ import annotations

import asyncio
import json
import random
from collections import Counter
from pathlib import Path
from typing import Any

from bench.crash import GatewayProcess, free_port
from gateway.planning.lorr import warehouse_problem
from gateway.server.clock import LoopClock
from sim_clients.connect import websocket_connector
from sim_clients.fleet import SimFleet
from tests.server.task_client import call, sse
from tracecheck import check_trace, read_trace

ROBOTS = 6


async def _task_events(port: int) -> list[Any]:
    """Every task event the gateway kept, from the first one."""
    last = (await call(port, "GET", "/tasks?limit=1")).json()["last_event"]
    events = []
    async with asyncio.timeout(30):
        async for ev in sse(port, "/tasks/events?after=0"):
            events.append(ev)
            if ev.id == last:
                break
    return events


async def _finished(port: int) -> int:
    return int((await call(port, "GET", "/tasks?limit=1")).json()["counts"]["finished"])


def test_a_killed_lifelong_gateway_continues_the_same_shift(tmp_path: Path) -> None:
    port = free_port()
    gw = GatewayProcess(tmp_path, port, speed=10.0, policy="none")
    config = tmp_path / "gateway.json"
    config.write_text(json.dumps({**json.loads(config.read_text()), "map": None,
                                  "autostart": True, "lifelong": {
                                      "robots": ROBOTS, "warehouse": [2, 3]}}))
    rng = random.Random(7)
    executed: Counter[tuple[int, int, int]] = Counter()
    completed: set[tuple[int, int]] = set()
    out: dict[str, Any] = {}

    def on_event(kind: str, plan: int, robot: int, index: int) -> None:
        if kind == "execute":
            executed[(plan, robot, index)] += 1
        elif kind == "finished":
            completed.add((robot, index))

    async def main() -> None:
        gw.start()
        fleet = SimFleet(websocket_connector(f"ws://127.0.0.1:{port}/ws"), range(ROBOTS),
                         clock=LoopClock(10.0), send_state=False, reconnect_delay_s=0.05,
                         duration_jitter=0.2, seed=3)
        fleet.on_event = on_event
        await fleet.start()
        try:
            await fleet.wait_connected(30.0)
            free = [[x, y] for x, y in warehouse_problem(ROBOTS, 0, (2, 3),
                                                         p_delay=0.0).grid.free_cells()]
            batch = {"tasks": [{"errands": [free[(7 * k) % len(free)],
                                            free[(13 * k + 5) % len(free)]]}
                               for k in range(6)], "idempotency_key": "wms-1"}
            assert (await call(port, "POST", "/tasks", batch)).status == 201
            finished_at_kill = []
            for _ in range(2):
                await asyncio.sleep(rng.uniform(1.5, 2.5))  # robots are mid-shift
                finished_at_kill.append(await _finished(port))
                gw.kill()
                out.setdefault("completed_at_kill", []).append(set(completed))
                await asyncio.sleep(rng.uniform(0.0, 0.3))
                await asyncio.to_thread(gw.start)
                out.setdefault("status", []).append(
                    (await asyncio.to_thread(gw.health))["gateway"])
                retry = await call(port, "POST", "/tasks", batch)
                out.setdefault("retry", []).append(retry.status)
            # the shift goes on: tasks keep finishing after the last restart
            async with asyncio.timeout(60):
                while await _finished(port) <= finished_at_kill[-1] + 2:
                    await asyncio.sleep(0.2)
            out["events"] = await _task_events(port)
        finally:
            await fleet.stop()
        out["errors"] = list(fleet.stats.errors)
        out["received"] = list(fleet.stats.received)

    try:
        asyncio.run(main())
    finally:
        gw.stop()
    assert out["status"] == ["running", "running"]
    assert out["retry"] == [200, 200]  # the batch's key survived: no task made twice
    records = read_trace(gw.trace)
    report = check_trace(records)
    assert report.collisions == [] and report.actions_run > 100
    # the shift was not stopped (the gateway was shut down under it): its running actions
    # never finish and it has no summary; nothing else may be wrong
    cut_off = [e for e in report.errors if e == "no summary record"
               or (e.startswith("robots ") and " never finished " in e)]
    assert len(cut_off) == 2 and report.errors == cut_off, report.errors
    # one shift: one start record, no trace moved aside, plan time never went back
    assert [r["type"] for r in records].count("plan") == 1
    assert not list(tmp_path.glob("trace.jsonl.*"))
    times = [float(r["t_ms"]) for r in records]
    assert times == sorted(times)
    # segments and action numbers go on: nothing numbered twice, no gap
    segments = [r["segment"] for r in records if r["type"] == "segment"]
    assert segments == list(range(len(segments))) and len(segments) > 10
    dispatched = [(r["robot"], r["action"]) for r in records if r["type"] == "dispatch"]
    finished = [(r["robot"], r["action"]) for r in records if r["type"] == "finish"]
    assert len(dispatched) == len(set(dispatched)) and len(finished) == len(set(finished))
    for robot in range(ROBOTS):
        mine = sorted(a for r, a in dispatched if r == robot)
        assert mine == list(range(len(mine)))
    # the robots saw one run id, executed nothing twice, and every completion they made
    # before a kill is in the trace (once, above)
    assert len({aid.split(".")[0] for aid in out["received"]}) == 1
    assert [k for k, n in executed.items() if n > 1] == []
    for before in out["completed_at_kill"]:
        assert before <= set(finished)
    assert out["errors"] == []
    # tasks: event ids go on, none finished twice, a started task never changed robots
    events = out["events"]
    assert [e.id for e in events] == list(range(1, len(events) + 1))
    by_task: dict[int, list[tuple[str, int]]] = {}
    for e in events:
        by_task.setdefault(e.data["task"], []).append((e.data["state"], e.data["robot"]))
    for task, states in by_task.items():
        assert [s for s, _ in states].count("finished") <= 1, (task, states)
        assert len({r for s, r in states if s in ("started", "finished")}) <= 1, (task, states)
