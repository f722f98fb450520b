"""A move stopped on the way (a TurtleBot's bumper): ``Executor.stopped`` (the protocol's
``blocked`` after ``started``) is accepted for a move, a replan cancels it, the robot
stands on the move's source again, and an abandoned replan dispatches the same move again;
the trace checker accepts such a trace."""

from __future__ import annotations

import pytest

from gateway.execution.commands import Cancel, Dispatch, SolveRequest
from gateway.execution.errors import ExecutionError
from gateway.execution.oneshot.executor import Executor
from gateway.execution.oneshot.monitor import NOT_STARTED, algorithm1
from gateway.planning.plan import Plan
from tests.execution.support import turning_plan
from tracecheck import check_trace

# A drives (0,0) -> (1,0) -> (2,0); B drives (5,5) -> (5,4), far away.
PLAN = Plan.of([[(0, 0), (1, 0), (2, 0)], [(5, 5), (5, 4)]])


def test_bumper_stop_is_cancelled_by_a_replan_and_redone_after_abandon() -> None:
    records: list[dict[str, object]] = []
    ex = Executor(PLAN, record=records.append)
    ex.start(0.0)
    ex.drain()
    ex.started(0, 0, 0, 0.0)
    ex.started(1, 0, 0, 0.0)
    ex.stopped(0, 0, 0, 400.0)  # bumper contact on the way to (1,0)
    with pytest.raises(ExecutionError, match="already blocked"):
        ex.stopped(0, 0, 0, 450.0)
    ex.finished(1, 0, 0, 1000.0)
    ex.request_replan(1200.0)
    assert [c for c in ex.drain() if isinstance(c, Cancel)] == [Cancel(0, 0, 0)]
    ex.cancelled(0, 0, 0, 1500.0)  # back on (0,0)
    (request,) = [c for c in ex.drain() if isinstance(c, SolveRequest)]
    assert request.starts == ((0, 0), (5, 4)) and ex.robot_cell(0) == (0, 0)
    v = ex.adg.vertex(0, 0)
    assert ex.monitor.state(v) == NOT_STARTED
    # the monitor forgot the start: equal to the full recomputation without it
    full = algorithm1(ex.adg, now_ms=ex.monitor.now_ms, action_ms=1000.0, release_ms=[0.0, 0.0],
                      started_ms=[None, None, 0.0], finished_ms=[None, None, 1000.0])
    snap = ex.monitor.snapshot()
    assert (snap.ts, snap.tc) == (full.ts, full.tc)
    ex.abandon_replan(1600.0)
    assert ex.drain() == [Dispatch(0, 0, 0, (0, 0), (1, 0), 1000.0)]
    ex.started(0, 0, 0, 1600.0)
    ex.finished(0, 0, 0, 2600.0)
    ex.drain()
    ex.started(0, 0, 1, 2600.0)
    ex.finished(0, 0, 1, 3600.0)
    assert ex.done and ex.soc_ms == 3600.0 + 1000.0
    records.append({"type": "summary", "soc_ms": 4600.0, "makespan_ms": 3600.0})
    report = check_trace(records)
    assert report.ok, (report.errors, report.collisions)
    assert [r["type"] for r in records if r.get("robot") == 0][:6] == [
        "dispatch", "start", "blocked", "cancel", "dispatch", "start"]


def test_a_bumper_stop_can_clear_and_the_move_finishes() -> None:
    ex = Executor(PLAN)
    ex.start(0.0)
    ex.started(0, 0, 0, 0.0)
    ex.stopped(0, 0, 0, 300.0)
    ex.unblocked(0, 0, 0, 2300.0)
    ex.finished(0, 0, 0, 3000.0)
    assert ex.robot_cell(0) == (1, 0)


def test_only_a_move_under_way_can_be_stopped() -> None:
    plan = turning_plan([[(0, 0), (0, 0), (1, 0)], [(5, 5), (5, 5), (5, 5)]],
                        [[3, 0, 0], [0, 0, 1]])
    ex = Executor(plan)
    ex.start(0.0)
    ex.started(0, 0, 0, 0.0)  # a turn
    ex.started(1, 0, 0, 0.0)  # a wait
    for robot in (0, 1):
        with pytest.raises(ExecutionError, match="only a move under way"):
            ex.stopped(robot, 0, 0, 10.0)
    ex.finished(1, 0, 0, 1000.0)
    ex.started(1, 0, 1, 1000.0)  # a turn
    with pytest.raises(ExecutionError, match="only a move under way"):
        ex.stopped(1, 0, 1, 1010.0)
    ex.finished(0, 0, 0, 1020.0)
    with pytest.raises(ExecutionError, match="only a move under way"):
        ex.stopped(0, 0, 1, 1030.0)  # dispatched, not started: that is blocked()
