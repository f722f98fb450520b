"""Executor: dispatching, trace records, the replanning state machine, and nonsense events."""

from __future__ import annotations

from collections.abc import Callable

import pytest

from gateway.execution.commands import (
    Cancel,
    Completed,
    Dispatch,
    PlanAdopted,
    SolveRequest,
    Trigger,
)
from gateway.execution.oneshot.executor import MONITOR_PERIOD_MS, ExecutionError, Executor, Mode
from gateway.execution.oneshot.policies import (
    NoReplan,
    OperatorOnly,
    RandomReplan,
    SlackReplan,
    make_policy,
)
from gateway.planning.plan import Plan
from tests.execution.support import snapshot
from tests.execution.test_adg import CORRIDOR, CROSSING

A, B = 0, 1


def _dispatches(ex: Executor) -> list[tuple[int, int]]:
    return [(c.robot, c.action) for c in ex.drain() if isinstance(c, Dispatch)]


def test_start_emits_plan_and_trace_records() -> None:
    log: list[dict[str, object]] = []
    ex = Executor(Plan.of(CROSSING), record=log.append)
    ex.start(0)
    cmds = ex.drain()
    assert cmds[0] == PlanAdopted(0, Plan.of(CROSSING))
    assert cmds[1:] == [Dispatch(0, A, 0, (0, 1), (1, 1), 1000.0),
                        Dispatch(0, B, 0, (1, 0), (1, 0), 1000.0)]
    assert log[0] == {"t_ms": 0.0, "type": "plan", "plan": 0,
                      "agents": [{"path": [[x, y] for x, y in p]} for p in CROSSING]}
    assert log[1:] == [{"t_ms": 0.0, "type": "dispatch", "plan": 0, "robot": A, "action": 0},
                       {"t_ms": 0.0, "type": "dispatch", "plan": 0, "robot": B, "action": 0}]
    ex.started(A, 0, 0, 10)
    ex.blocked(B, 0, 0, 20)
    ex.unblocked(B, 0, 0, 30)
    ex.started(B, 0, 0, 30)
    ex.finished(A, 0, 0, 1010)
    assert [(r["type"], r["t_ms"]) for r in log[3:]] == [
        ("start", 10.0), ("blocked", 20.0), ("unblocked", 30.0), ("start", 30.0),
        ("finish", 1010.0), ("dispatch", 1010.0)]
    assert ex.robot_cell(A) == (1, 1) and ex.robot_cell(B) == (1, 0)
    assert isinstance(log[3]["t_ms"], int)  # t_ms exactly as the driver gave it
    assert MONITOR_PERIOD_MS == 100


def test_drop_waits_dispatches_path_indices_and_skips_waits() -> None:
    ex = Executor(Plan.of(CROSSING), drop_waits=True)
    ex.start(0)
    assert _dispatches(ex) == [(A, 0)]
    ex.started(A, 0, 0, 0)
    ex.finished(A, 0, 0, 1000)
    ex.started(A, 0, 1, 1000)
    ex.finished(A, 0, 1, 2000)
    assert ex.drain() == [Dispatch(0, A, 1, (1, 1), (2, 1), 1000.0),
                          Dispatch(0, B, 2, (1, 0), (1, 1), 1000.0)]
    with pytest.raises(ExecutionError, match="is a wait"):
        ex.started(B, 0, 1, 2000)


def test_a_plan_without_actions_completes_at_start() -> None:
    ex = Executor(Plan.of([[(0, 0)], [(1, 1)]]))
    ex.start(0)
    assert ex.drain()[1:] == [Completed(0.0, 0.0)] and ex.done


def _crossing_with_b_blocked() -> tuple[Executor, list[dict[str, object]]]:
    # A runs a_0; B's wait a_0 is dispatched and (say) blocked; the operator asks to replan.
    log: list[dict[str, object]] = []
    ex = Executor(Plan.of(CROSSING), policy=OperatorOnly(), record=log.append)
    ex.start(0)
    ex.started(A, 0, 0, 0)
    ex.blocked(B, 0, 0, 0)
    ex.drain()
    ex.request_replan(400)
    return ex, log


def test_replan_cancels_blocked_lets_running_finish_then_solves() -> None:
    ex, log = _crossing_with_b_blocked()
    assert ex.drain() == [Trigger("operator", 0.0), Cancel(0, B, 0)]
    assert log[-1] == {"t_ms": 400.0, "type": "trigger", "policy": "operator",
                       "fleet_slack_ms": 0.0}
    assert ex.mode is Mode.STOPPING
    ex.cancelled(B, 0, 0, 450)
    assert ex.drain() == []  # A is still moving
    ex.finished(A, 0, 0, 1000)
    assert ex.drain() == [SolveRequest(((1, 1), (1, 0)), ((2, 1), (1, 2)))]  # no dispatch
    assert log[-2]["type"] == "cancel" and log[-1]["type"] == "finish"
    with pytest.raises(ExecutionError, match="starts at"):
        ex.adopt_plan(Plan.of(CROSSING), 1100)
    new = Plan.of([[(1, 1), (2, 1)], [(1, 0), (1, 0), (1, 0), (1, 1), (1, 2)]])
    ex.adopt_plan(new, 1200)
    cmds = ex.drain()
    assert cmds[0] == PlanAdopted(1, new) and ex.plan_id == 1 and ex.replans == 1
    assert cmds[1:] == [Dispatch(1, A, 0, (1, 1), (2, 1), 1000.0),
                        Dispatch(1, B, 0, (1, 0), (1, 0), 1000.0)]
    assert log[-3]["type"] == "plan" and log[-3]["plan"] == 1
    # an event for the old plan is now rejected
    with pytest.raises(ExecutionError, match="refers to plan 0"):
        ex.started(A, 0, 1, 1300)
    ex.started(A, 1, 0, 1300)
    for i in range(4):
        ex.started(B, 1, i, 1300 + 1000 * i)
        if i == 0:
            ex.finished(A, 1, 0, 2300)
        ex.finished(B, 1, i, 2300 + 1000 * i)
    # A ends at 2300, B at 5300: the stop and the solve are charged to both
    assert ex.done and (ex.soc_ms, ex.makespan_ms) == (7600, 5300)
    assert ex.drain()[-1] == Completed(7600, 5300)


def test_late_start_after_cancel_and_abandon_resumes_old_plan() -> None:
    ex, _ = _crossing_with_b_blocked()
    ex.drain()
    ex.started(B, 0, 0, 420)  # B had begun before the Cancel arrived: legitimate
    ex.finished(A, 0, 0, 1000)
    assert ex.drain() == []
    ex.finished(B, 0, 0, 1420)
    assert ex.drain() == [SolveRequest(((1, 1), (1, 0)), ((2, 1), (1, 2)))]
    ex.abandon_replan(1500)
    assert _dispatches(ex) == [(A, 1), (B, 1)]
    assert ex.mode is Mode.RUNNING and ex.plan_id == 0
    with pytest.raises(ExecutionError, match="budget of 1 replan"):
        ex.request_replan(1600)
    assert ex.next_wakeup_ms() is None


def test_cancelled_action_is_dispatched_again_after_abandon() -> None:
    ex, _ = _crossing_with_b_blocked()
    ex.cancelled(B, 0, 0, 410)
    ex.finished(A, 0, 0, 1000)
    ex.drain()
    assert ex.robot_cell(B) == (1, 0)
    ex.abandon_replan(1000)
    assert _dispatches(ex) == [(A, 1), (B, 0)]


def test_stop_with_nothing_left_completes_instead_of_solving() -> None:
    # One robot, one action, already running when the replan is decided: nothing to cancel,
    ex = Executor(Plan.of([[(0, 0), (1, 0)]]), max_replans=2)
    ex.start(0)
    ex.started(0, 0, 0, 0)
    ex.drain()
    ex.request_replan(10)
    assert ex.drain() == [Trigger("operator", 0.0)]
    ex.finished(0, 0, 0, 1000)
    # nothing was left to do, so the run completes instead of asking for a plan
    assert ex.drain()[-1] == Completed(1000, 1000) and ex.done


def test_random_policy_fires_once_at_its_drawn_time() -> None:
    pol = RandomReplan(7, makespan_lb_ms=20_000)
    assert 3000 <= pol.replan_at_ms <= 17_000 and pol.replan_at_ms == int(pol.replan_at_ms)
    assert RandomReplan(7, makespan_lb_ms=20_000).replan_at_ms == pol.replan_at_ms
    assert RandomReplan(1, makespan_lb_ms=4000).replan_at_ms == 3000  # empty interval: T_a
    ex = Executor(Plan.of(CORRIDOR), policy=pol)
    ex.start(0)
    assert ex.next_wakeup_ms() == pol.replan_at_ms
    ex.tick(pol.replan_at_ms - 1)
    assert not [c for c in ex.drain() if isinstance(c, Trigger)]
    ex.tick(pol.replan_at_ms)
    assert [c for c in ex.drain() if isinstance(c, Trigger)] == [Trigger("random", 0.0)]
    assert ex.next_wakeup_ms() is None


def test_make_policy_names() -> None:
    assert isinstance(make_policy("none"), NoReplan)
    slack = make_policy("slack", threshold_ms=5)
    assert isinstance(slack, SlackReplan) and slack.threshold_ms == 5
    assert make_policy("operator").name == "operator"
    assert make_policy("random", seed=3, makespan_lb_ms=9000).name == "random"
    with pytest.raises(ValueError, match="unknown replanning policy"):
        make_policy("sometimes")
    assert SlackReplan().threshold_ms == 2000


# ---------------------------------------------------------------------- nonsense events

def _running() -> Executor:
    ex = Executor(Plan.of(CROSSING), record=lambda r: None)
    ex.start(0)
    ex.started(A, 0, 0, 100)  # A moving, B's wait dispatched
    ex.drain()
    return ex


NONSENSE: list[tuple[str, Callable[[Executor], None], str]] = [
    ("unknown robot", lambda ex: ex.started(2, 0, 0, 200), "unknown robot 2"),
    ("negative robot", lambda ex: ex.finished(-1, 0, 0, 200), "unknown robot -1"),
    ("unknown plan", lambda ex: ex.started(B, 1, 0, 200), "refers to plan 1"),
    ("unknown action", lambda ex: ex.started(B, 0, 9, 200), "no action 9"),
    ("finish not started", lambda ex: ex.finished(B, 0, 0, 200), "has not started"),
    ("finish not dispatched", lambda ex: ex.finished(A, 0, 1, 200), "not dispatched"),
    ("start twice", lambda ex: ex.started(A, 0, 0, 200), "already started"),
    ("start not ready", lambda ex: ex.started(B, 0, 2, 200), "not dispatched"),
    ("blocked while moving", lambda ex: ex.blocked(A, 0, 0, 200), "already started"),
    ("unblocked not blocked", lambda ex: ex.unblocked(B, 0, 0, 200), "not blocked"),
    ("cancelled without cancel", lambda ex: ex.cancelled(B, 0, 0, 200), "no Cancel"),
    ("time backwards", lambda ex: ex.started(B, 0, 0, 50), "time went backwards"),
    ("time NaN", lambda ex: ex.tick(float("nan")), "time went backwards"),
    ("tick backwards", lambda ex: ex.tick(99), "time went backwards"),
    ("start twice", lambda ex: ex.start(200), "already called"),
    ("adopt unrequested", lambda ex: ex.adopt_plan(Plan.of(CROSSING), 200), "no plan was"),
    ("abandon unrequested", lambda ex: ex.abandon_replan(200), "no plan was"),
]


@pytest.mark.parametrize(("name", "event", "message"), NONSENSE, ids=[n for n, _, _ in NONSENSE])
def test_nonsense_event_raises_and_changes_nothing(
        name: str, event: Callable[[Executor], None], message: str) -> None:
    ex = _running()
    before = snapshot(ex)
    with pytest.raises(ExecutionError, match=message):
        event(ex)
    assert snapshot(ex) == before
    assert ex.drain() == []


def test_finished_action_reported_again_is_rejected() -> None:
    ex = _running()
    ex.finished(A, 0, 0, 1100)
    before = snapshot(ex)
    with pytest.raises(ExecutionError, match="is finished"):
        ex.finished(A, 0, 0, 1200)
    assert snapshot(ex) == before


def test_events_before_start_are_rejected() -> None:
    ex = Executor(Plan.of(CROSSING))
    before = snapshot(ex)
    with pytest.raises(ExecutionError, match="call start"):
        ex.started(A, 0, 0, 0)
    with pytest.raises(ExecutionError, match="call start"):
        ex.tick(0)
    assert snapshot(ex) == before


@pytest.mark.parametrize(("paths", "message"), [
    ([[(1, 1), (2, 1)]], "1 paths for 2 robots"),
    ([[(1, 1), (2, 1)], [(1, 0), (1, 1)]], "ends at"),
    ([[(1, 1), (2, 1)], [(1, 0), (1, 2)]], "jumps from"),
    ([[(0, 1), (1, 1), (2, 1)], [(1, 0), (1, 1), (1, 2)]], "starts at"),
])
def test_bad_new_plans_are_rejected_without_change(paths: list[list[tuple[int, int]]],
                                                   message: str) -> None:
    ex, _ = _crossing_with_b_blocked()
    ex.cancelled(B, 0, 0, 410)
    ex.finished(A, 0, 0, 1000)
    ex.drain()
    before = snapshot(ex)
    with pytest.raises(ExecutionError, match=message):
        ex.adopt_plan(Plan.of(paths), 1100)
    assert snapshot(ex) == before


def test_operator_replan_refused_when_not_running() -> None:
    ex, _ = _crossing_with_b_blocked()  # STOPPING
    before = snapshot(ex)
    with pytest.raises(ExecutionError, match="executor is stopping"):
        ex.request_replan(500)
    assert snapshot(ex) == before
    with pytest.raises(ExecutionError, match="max_replans"):
        Executor(Plan.of(CROSSING), max_replans=-1)
