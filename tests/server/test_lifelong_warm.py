"""The lifelong gateway's planning schedule and its warm-up: planning calls keep their period
(a call made late does not push the later ones back), the distance tables of submitted tasks
are computed in the planner process before anyone asks for them (the same tables as computed
in place), and a planner process started without waiting for it (a restarting gateway
replays its journal meanwhile) answers and survives a kill."""

from __future__ import annotations

import asyncio
import os
import signal
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from gateway.execution.lifelong.errands import TaskDistances
from gateway.execution.lifelong.executor import LifelongExecutor, PlanRequest, WindowPlanner
from gateway.execution.lifelong.tasks import TaskPool
from gateway.planning.distance import distance_tables
from gateway.planning.lorr import warehouse_problem
from gateway.planning.pibt import UNREACHABLE
from gateway.server.clock import VirtualClock, run_virtual
from gateway.server.config import GatewayConfig, LifelongSettings
from gateway.server.gateway import Gateway
from gateway.server.runs.planner_process import PlannerDied, PlannerProcess, Warm
from sim_clients.fleet import SimFleet
from sim_clients.shift import run_shift
from tests.server.task_client import call
from tracecheck import check_trace, read_trace


def test_a_late_planning_call_does_not_push_the_later_ones_back() -> None:
    prob = warehouse_problem(6, 1, (2, 3), p_delay=0.0)
    ex = LifelongExecutor(prob.grid, prob.starts, [0] * 6, TaskPool(prob.tasks, 9),
                          distances=TaskDistances(prob.grid), period_ms=1000.0)
    planner = WindowPlanner(prob.grid, 6, True)

    def answer(now: float) -> None:
        req = next(c for c in ex.drain() if isinstance(c, PlanRequest))
        ex.adopt(planner(req), now)

    ex.start(0.0)
    answer(30.0)
    ex.tick(1070.0)  # the driver ticked 70 ms late: the call is made now ...
    assert ex.calls == 2
    answer(1100.0)
    assert ex.next_wakeup_ms() == 2000.0  # ... and the next one is due a period after 1000
    ex.tick(2000.0)
    assert ex.calls == 3
    answer(2900.0)  # late by 900 ms: still due at 3000
    assert ex.next_wakeup_ms() == 3000.0
    ex.tick(3000.0)
    answer(5100.0)  # more than a period late: the call due at 4000 is made at once, the one
    ex.tick(5100.0)  # due at 5000 right after it, then the period starts again from there
    assert ex.calls == 5 and ex.next_wakeup_ms() is None
    answer(5150.0)
    assert ex.next_wakeup_ms() == 5100.0
    ex.tick(5150.0)
    answer(5200.0)
    assert ex.calls == 6 and ex.next_wakeup_ms() == 6100.0


def test_the_gateway_calls_the_planner_at_its_period_off_the_tick_grid(
        tmp_path: Path) -> None:
    """Virtual time, each call charged 120 ms, a period of 1050 ms (not a multiple of the
    100 ms monitor tick): segment k is adopted at exactly k x 1050 + 120 ms (the engine wakes
    at the executor's due time instead of the next tick, and no period is pushed back)."""
    trace = tmp_path / "trace.jsonl"

    async def main() -> None:
        config = GatewayConfig(port=0, map=None, autostart=True, log_level="WARNING",
                               trace=trace, lifelong=LifelongSettings(
                                   robots=6, warehouse=(2, 3), period_ms=1050.0,
                                   threshold_ms=None))
        async with Gateway(config, clock=VirtualClock(solver_time=120.0)) as gw:
            fleet = SimFleet(gw.connect, range(6), clock=gw.clock, send_state=False)
            stats = await run_shift(gw, fleet, 12_000.0)
            assert stats.lost == stats.duplicated == stats.collisions == 0

    run_virtual(main())
    records = read_trace(trace)
    adopted = [r["t_ms"] for r in records if r["type"] == "segment"]
    assert len(adopted) >= 11
    assert adopted == pytest.approx([k * 1050.0 + 120.0 for k in range(len(adopted))])
    assert check_trace(records).ok


def _oracle(grid: Any, cell: int) -> list[int]:
    """Moves to ``cell`` from every free cell by the plain search, capped as the tables are."""
    row = distance_tables(grid, [grid.cell(cell)])[0][grid.free.ravel()]
    return np.where(row < 0, UNREACHABLE, np.minimum(row, UNREACHABLE)).tolist()


def test_submitted_tasks_tables_are_computed_in_the_planner_process_before_the_shift(
        ) -> None:
    """Tasks posted through the task API over 127.0.0.1, the shift not started: the
    scheduler's tables of their first errands and legs arrive from the planner process
    (no planning call was made, the loop computed none), equal to the plain search's."""
    out: dict[str, Any] = {}

    async def main() -> None:
        config = GatewayConfig(port=0, map=None, autostart=False, log_level="WARNING",
                               lifelong=LifelongSettings(robots=8, warehouse=(2, 3),
                                                         task_list=False))
        async with Gateway(config) as gw:
            run = gw.engine.lifelong
            assert run is not None
            port = await gw.listen()
            grid = run.shift.grid
            free = [c for c in range(grid.size) if grid.free.ravel()[c]]
            tasks = [[free[(37 * i) % len(free)], free[(11 * i + 3) % len(free)],
                      free[(5 * i + 1) % len(free)]] for i in range(12)]
            reply = await call(port, "POST", "/tasks", {"tasks": [
                {"errands": [list(grid.cell(c)) for c in t]} for t in tasks]})
            assert reply.status == 201
            space = run.executor.distances.space
            want = sorted({c for t in tasks for c in t[:2]})
            for _ in range(1200):  # a bound for a loaded machine, not a duration
                if all(space.cached(c) for c in want):
                    break
                await asyncio.sleep(0.05)
            out["calls"] = run.executor.calls
            out["status"] = run.status
            out["tables"] = {c: list(space.distances(c)) for c in want}
            out["last_only"] = sorted({t[2] for t in tasks} - {c for t in tasks
                                                               for c in t[:2]})
            out["cached_last"] = [c for c in out["last_only"] if space.cached(c)]
            out["grid"] = grid

    asyncio.run(main())
    assert out["calls"] == 0 and out["status"] == "loaded"
    assert out["tables"] and all(table == _oracle(out["grid"], c)
                                 for c, table in out["tables"].items())
    assert out["last_only"] and out["cached_last"] == []  # only what the scheduler reads


def test_a_planner_process_started_without_waiting_answers_and_survives_a_kill() -> None:
    prob = warehouse_problem(4, 0, (2, 3), p_delay=0.0)
    planner = PlannerProcess(prob.grid, 4, turning=True)
    try:
        planner.start(wait=False)
        pid = planner.pid
        assert pid is not None
        cells = tuple(sorted({t[0] for t in prob.tasks[:6]}))
        tables = planner.warm(Warm(cells, cells))
        assert {c: list(t) for c, t in tables.items()} == {c: _oracle(prob.grid, c)
                                                           for c in cells}
        os.kill(pid, signal.SIGKILL)
        with pytest.raises(PlannerDied, match=rf"pid {pid}\) died"):
            planner.warm(Warm(cells, ()))
        req = PlanRequest(0, prob.starts, tuple((c,) for c in cells[:4]), (0,) * 4, (), 3)
        segment, _ = planner.call(req)  # a new worker
        assert planner.starts == 2 and len(segment.states) == 4
    finally:
        planner.close()
