"""``/metrics`` of a warehouse shift (issue 27 item 14), read over real HTTP from a journaled
lifelong gateway whose simulated robots do submitted tasks over websockets: the queue by state,
tasks finished, completion times, planner calls and journal commits agree with the task API and
the run; every query of the Grafana dashboard in deploy/ names a metric the gateway exports."""

from __future__ import annotations

import asyncio
import json
import re
from pathlib import Path
from typing import Any

from gateway.server.gateway import Gateway
from sim_clients.connect import websocket_connector
from sim_clients.fleet import SimFleet
from sim_clients.shift import start_shift, stop_shift
from tests.server.task_client import call
from tests.server.test_task_api import ROBOTS, grid_of, lifelong_config

DASHBOARD = Path(__file__).resolve().parents[2] / "deploy" / "grafana-dashboard.json"
SUFFIXES = {"counter": ("",), "gauge": ("",), "histogram": ("_bucket", "_sum", "_count"),
            "summary": ("", "_sum", "_count")}
TASKS = 12


def samples(text: str) -> dict[str, float]:
    """``name{labels}`` -> value of every sample of a Prometheus text exposition."""
    out = {}
    for line in text.splitlines():
        if line and not line.startswith("#"):
            key, value = line.rsplit(" ", 1)
            out[key] = float(value)
    return out


def exported_names(text: str) -> set[str]:
    """Every sample name the exposition declares (``# TYPE``; a counter's is declared with its
    ``_total``), with or without samples yet (a labelled metric has none until its first
    label set)."""
    names = set()
    for m in re.finditer(r"^# TYPE (\S+) (\S+)$", text, re.MULTILINE):
        names |= {m[1] + s for s in SUFFIXES[m[2]]}
    return names


def dashboard_queries() -> list[str]:
    """Every PromQL expression of the dashboard (its panels' targets and its variables)."""
    dash = json.loads(DASHBOARD.read_text())
    exprs = [t["expr"] for p in dash["panels"] for t in p["targets"]]
    exprs += [v["query"] for v in dash["templating"]["list"] if v["type"] == "query"]
    return exprs


def test_shift_metrics_agree_with_the_task_api_and_the_dashboard_reads_them(
        tmp_path: Path) -> None:
    out: dict[str, Any] = {}

    async def main() -> None:
        config = lifelong_config(journal=tmp_path / "journal.sqlite")
        async with Gateway(config) as gw:
            port = await gw.listen()
            run = gw.engine.lifelong
            assert run is not None
            free = list(grid_of(gw).free_cells())
            tasks = [{"errands": [list(free[(7 * k) % len(free)]),
                                  list(free[(13 * k + 5) % len(free)])]} for k in range(TASKS)]
            assert (await call(port, "POST", "/tasks", {"tasks": tasks})).status == 201
            await call(port, "POST", "/tasks/0/pause")
            out["before"] = (await call(port, "GET", "/metrics")).body.decode()
            await call(port, "POST", "/tasks/0/resume")
            fleet = SimFleet(websocket_connector(f"ws://127.0.0.1:{port}/ws"), range(ROBOTS),
                             clock=gw.clock, send_state=False)
            await start_shift(gw, fleet)
            async with asyncio.timeout(120):
                while run.tasks.finished < TASKS:
                    await asyncio.sleep(0.1)
            await stop_shift(gw, fleet)
            await fleet.stop()
            calls_before = len(run.planner_ms)
            out["after"] = (await call(port, "GET", "/metrics")).body.decode()
            out["calls"] = (calls_before, len(run.planner_ms))
            out["tasks"] = (await call(port, "GET", "/tasks")).json()["tasks"]

    asyncio.run(main())
    before, after = samples(out["before"]), samples(out["after"])
    # before the shift: every task waits, one held by the operator
    assert before['fleetgate_tasks{state="queued"}'] == TASKS - 1
    assert before['fleetgate_tasks{state="paused"}'] == 1
    assert before['fleetgate_tasks{state="assigned"}'] == 0
    assert before["fleetgate_tasks_finished_total"] == 0
    # after: all done, each completion time as the task API shows it
    for state in ("queued", "paused", "assigned", "started"):
        assert after[f'fleetgate_tasks{{state="{state}"}}'] == 0
    assert after["fleetgate_tasks_finished_total"] == TASKS
    assert after["fleetgate_task_completion_seconds_count"] == TASKS
    completion = sum(t["finished_ms"] - t["submitted_ms"] for t in out["tasks"]) / 1000.0
    assert abs(after["fleetgate_task_completion_seconds_sum"] - completion) < 1e-6
    # each finished task's wait for a robot, in seconds: some, and never more than its life
    assert after["fleetgate_task_wait_seconds_count"] == TASKS
    assert 0.0 < after["fleetgate_task_wait_seconds_sum"] <= completion
    assert after['fleetgate_task_wait_seconds_bucket{le="+Inf"}'] == TASKS
    low, high = out["calls"]
    assert 1 <= low <= after['fleetgate_planner_call_seconds_count{purpose="window"}'] <= high
    assert after["fleetgate_journal_commit_seconds_count"] > TASKS
    assert after['fleetgate_journal_commit_seconds_bucket{le="+Inf"}'] == \
        after["fleetgate_journal_commit_seconds_count"]
    # the dashboard reads only what the gateway exports
    exported = exported_names(out["after"])
    queries = dashboard_queries()
    assert len(queries) >= 10
    for expr in queries:
        named = set(re.findall(r"\bfleetgate_[a-z_]+", expr))
        assert named, f"a dashboard query names no fleetgate metric: {expr}"
        assert named <= exported, f"{expr}: not exported: {sorted(named - exported)}"
    for metric in ("fleetgate_tasks", "fleetgate_tasks_finished_total",
                   "fleetgate_task_assignment_wait_seconds",
                   "fleetgate_task_completion_seconds_bucket",
                   "fleetgate_planner_call_seconds_bucket",
                   "fleetgate_journal_commit_seconds_bucket"):
        assert any(metric in q for q in queries), f"no panel shows {metric}"


def test_a_restarted_gateway_does_not_count_finishes_again(tmp_path: Path) -> None:
    """The finishes a restarted gateway replays from its journal were counted by the process
    before it: the new one's counter starts at 0 (a Prometheus counter reset), not at them."""
    out: dict[str, Any] = {}
    config = lifelong_config(journal=tmp_path / "journal.sqlite")

    async def first() -> None:
        async with Gateway(config) as gw:
            port = await gw.listen()
            run = gw.engine.lifelong
            assert run is not None
            free = list(grid_of(gw).free_cells())
            await call(port, "POST", "/tasks", {"tasks": [
                {"errands": [list(free[3 * k]), list(free[-3 * k - 1])]} for k in range(4)]})
            fleet = SimFleet(websocket_connector(f"ws://127.0.0.1:{port}/ws"), range(ROBOTS),
                             clock=gw.clock, send_state=False)
            await start_shift(gw, fleet)
            async with asyncio.timeout(120):
                while run.tasks.finished < 2:
                    await asyncio.sleep(0.05)
            out["first"] = samples((await call(port, "GET", "/metrics")).body.decode())
            await fleet.stop()

    async def second() -> None:
        async with Gateway(config) as gw:
            port = await gw.listen()
            run = gw.engine.lifelong
            assert run is not None
            out["replayed"] = run.tasks.finished
            await asyncio.sleep(0.3)  # a few owner steps and commits
            out["second"] = samples((await call(port, "GET", "/metrics")).body.decode())

    asyncio.run(first())
    asyncio.run(second())
    assert out["first"]["fleetgate_tasks_finished_total"] >= 2
    assert out["replayed"] >= 2
    assert out["second"]["fleetgate_tasks_finished_total"] == 0
    assert out["second"]["fleetgate_task_completion_seconds_count"] == 0
    assert out["second"]["fleetgate_task_wait_seconds_count"] == 0
