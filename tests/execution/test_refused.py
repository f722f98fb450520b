"""A robot refuses a dispatched action (protocol v2 ``refused``): ``Executor.refused`` takes
it and the robot's later dispatched actions back (not executed), dispatches the robot nothing
more of the plan, and a replan (adopted or abandoned) gives it work again; the trace checker
accepts such a trace."""

from __future__ import annotations

import pytest

from gateway.execution.commands import Dispatch, SolveRequest
from gateway.execution.errors import ExecutionError
from gateway.execution.oneshot.executor import Executor, Mode
from gateway.planning.plan import Plan
from tracecheck import check_trace

# A drives (0,0) -> (1,0) -> (2,0) -> (3,0); B drives (5,5) -> (5,4), far away.
PLAN = Plan.of([[(0, 0), (1, 0), (2, 0), (3, 0)], [(5, 5), (5, 4)]])


def dispatched(ex: Executor, robot: int) -> list[int]:
    return [c.action for c in ex.drain() if isinstance(c, Dispatch) and c.robot == robot]


def test_a_refused_action_and_those_behind_it_are_taken_back_until_a_replan() -> None:
    records: list[dict[str, object]] = []
    ex = Executor(PLAN, record=records.append, lookahead=1)
    ex.start(0.0)
    assert dispatched(ex, 0) == [0, 1]
    ex.refused(0, 0, 0, 10.0, "pose_mismatch: the robot faces N")
    assert ex.drain() == []  # nothing is dispatched to the refusing robot again
    with pytest.raises(ExecutionError, match="not dispatched"):
        ex.started(0, 0, 0, 20.0)
    ex.started(1, 0, 0, 20.0)
    ex.finished(1, 0, 0, 1020.0)
    assert ex.drain() == [] and ex.mode is Mode.RUNNING and ex.robot_cell(0) == (0, 0)
    refusals = [r for r in records if r["type"] == "refused"]
    assert refusals == [
        {"t_ms": 10.0, "type": "refused", "plan": 0, "robot": 0, "action": 0,
         "reason": "pose_mismatch: the robot faces N"},
        {"t_ms": 10.0, "type": "refused", "plan": 0, "robot": 0, "action": 1}]
    # the replan has nothing to wait for: the refusing robot holds nothing
    ex.request_replan(1100.0)
    (request,) = [c for c in ex.drain() if isinstance(c, SolveRequest)]
    assert request.starts == ((0, 0), (5, 4))
    ex.adopt_plan(Plan.of([[(0, 0), (1, 0), (2, 0), (3, 0)], [(5, 4)]]), 1200.0)
    assert dispatched(ex, 0) == [0, 1]
    t = 1200.0
    for i in range(3):
        ex.started(0, 1, i, t)
        t += 1000.0
        ex.finished(0, 1, i, t)
    assert ex.done and ex.soc_ms == t + 1020.0
    records.append({"type": "summary", "soc_ms": ex.soc_ms, "makespan_ms": ex.makespan_ms})
    report = check_trace(records)
    assert report.ok, (report.errors, report.collisions)


def test_an_abandoned_replan_dispatches_the_refused_action_again() -> None:
    ex = Executor(PLAN, max_replans=1)
    ex.start(0.0)
    ex.drain()
    ex.refused(0, 0, 0, 10.0)
    ex.request_replan(20.0)
    ex.cancelled(1, 0, 0, 25.0)  # B had not started
    ex.abandon_replan(30.0)
    assert dispatched(ex, 0) == [0]


def test_only_a_dispatched_action_that_has_not_started_can_be_refused() -> None:
    ex = Executor(PLAN)
    ex.start(0.0)
    ex.started(0, 0, 0, 0.0)
    with pytest.raises(ExecutionError, match="already started"):
        ex.refused(0, 0, 0, 10.0)
    with pytest.raises(ExecutionError, match="not dispatched"):
        ex.refused(0, 0, 2, 10.0)


def test_the_trace_checker_refuses_a_refusal_of_a_started_action() -> None:
    plan = {"t_ms": 0.0, "type": "plan", "plan": 0, "agents": [{"path": [[0, 0], [1, 0]]}]}
    ev = {"plan": 0, "robot": 0, "action": 0}
    records = [plan, {"t_ms": 0.0, "type": "dispatch", **ev},
               {"t_ms": 0.0, "type": "start", **ev}, {"t_ms": 5.0, "type": "refused", **ev}]
    report = check_trace(records)
    assert any("refused action (0, 0) that is not waiting to start" in e
               for e in report.errors), report.errors
