"""The simulated robot's state machine on a World (paper section 4.2), event by event."""

from __future__ import annotations

import pytest

from gateway.execution.commands import Dispatch
from sim_clients.robot import RobotState, SimRobot, SimRobotError
from sim_clients.world import INTRUDER, World


def kinds(events: list) -> list[tuple[str, float]]:
    return [(e.kind, e.t_ms) for e in events]


def test_world_records_occupancy_and_collisions() -> None:
    w = World([(0, 0), (1, 0)])
    assert not w.is_free((0, 0)) and w.is_free((2, 0))
    w.occupy((2, 0), INTRUDER, 5.0)
    assert w.holders((2, 0)) == (INTRUDER,)
    w.occupy((2, 0), 1, 7.0)  # a second occupant is recorded, not refused
    assert [(c.t_ms, c.cell, c.newcomer, c.holders) for c in w.collisions] == [
        (7.0, (2, 0), 1, (INTRUDER,))]
    w.release((2, 0), INTRUDER)
    w.release((2, 0), 1)
    assert w.is_free((2, 0))
    with pytest.raises(ValueError, match="not on"):
        w.release((2, 0), 1)
    with pytest.raises(ValueError, match="already on"):
        w.occupy((0, 0), 0, 0.0)


def test_free_move_holds_both_cells_then_frees_source() -> None:
    w = World([(0, 0)])
    r = SimRobot(0, w, (0, 0))
    assert kinds(r.dispatch(Dispatch(0, 0, 0, (0, 0), (1, 0), 1000.0), 0.0)) == [("started", 0.0)]
    assert r.state is RobotState.MOVING
    assert w.holders((0, 0)) == (0,) and w.holders((1, 0)) == (0,)
    assert r.next_wakeup_ms() == 1000.0
    assert r.wake(999.0) == []  # not due yet
    assert kinds(r.wake(1000.0)) == [("finished", 1000.0)]
    assert w.is_free((0, 0)) and w.holders((1, 0)) == (0,)
    assert r.cell == (1, 0) and r.state is RobotState.IDLE and r.next_wakeup_ms() is None


def test_blocked_robot_rechecks_every_100ms_and_starts_when_freed() -> None:
    w = World([(0, 0), (1, 0)])
    r = SimRobot(0, w, (0, 0))
    assert kinds(r.dispatch(Dispatch(0, 0, 3, (0, 0), (1, 0), 1000.0), 50.0)) == [
        ("blocked", 50.0)]
    assert r.next_wakeup_ms() == 150.0
    assert r.wake(150.0) == [] and r.next_wakeup_ms() == 250.0
    w.release((1, 0), 1)
    # freed at some point after 150: the robot notices at its next look, 250
    events = r.wake(250.0)
    assert kinds(events) == [("unblocked", 250.0), ("started", 250.0)]
    assert {e.action for e in events} == {3}
    assert kinds(r.wake(1250.0)) == [("finished", 1250.0)]


def test_wait_action_needs_no_free_cell_and_extra_delay_lengthens_it() -> None:
    w = World([(0, 0)])
    r = SimRobot(0, w, (0, 0))
    assert kinds(r.dispatch(Dispatch(0, 0, 0, (0, 0), (0, 0), 1000.0), 0.0, extra_ms=250.0)) == [
        ("started", 0.0)]
    assert kinds(r.wake(1250.0)) == [("finished", 1250.0)]
    assert w.holders((0, 0)) == (0,)


def test_cancel_only_while_blocked() -> None:
    w = World([(0, 0), (1, 0)])
    r = SimRobot(0, w, (0, 0))
    r.dispatch(Dispatch(0, 0, 0, (0, 0), (1, 0), 1000.0), 0.0)
    assert r.cancel(0, 1, 10.0) == []  # stale: another action
    assert kinds(r.cancel(0, 0, 20.0)) == [("cancelled", 20.0)]
    assert r.state is RobotState.IDLE and r.next_wakeup_ms() is None and r.cell == (0, 0)
    # a new plan's action from the same cell is accepted
    assert kinds(r.dispatch(Dispatch(1, 0, 0, (0, 0), (0, 1), 1000.0), 30.0)) == [
        ("started", 30.0)]
    assert r.cancel(1, 0, 40.0) == []  # moving: it finishes as usual
    assert kinds(r.wake(1030.0)) == [("finished", 1030.0)]


def test_a_cancelled_action_can_be_dispatched_again() -> None:
    # the replan was abandoned: the executor dispatches the same action of the old plan again
    w = World([(0, 0), (1, 0)])
    r = SimRobot(0, w, (0, 0))
    d = Dispatch(0, 0, 2, (0, 0), (1, 0), 1000.0)
    r.dispatch(d, 0.0)
    r.cancel(0, 2, 100.0)
    assert kinds(r.dispatch(d, 300.0)) == [("blocked", 300.0)]
    w.release((1, 0), 1)
    assert kinds(r.wake(400.0)) == [("unblocked", 400.0), ("started", 400.0)]


def test_bad_dispatches_are_refused_and_duplicates_dropped() -> None:
    w = World([(0, 0), (5, 5)])
    r = SimRobot(0, w, (0, 0))
    with pytest.raises(SimRobotError, match="is on"):
        r.dispatch(Dispatch(0, 0, 0, (1, 0), (2, 0), 1000.0), 0.0)
    with pytest.raises(SimRobotError, match="for robot 1"):
        r.dispatch(Dispatch(0, 1, 0, (0, 0), (1, 0), 1000.0), 0.0)
    d = Dispatch(0, 0, 0, (0, 0), (1, 0), 1000.0)
    r.dispatch(d, 0.0)
    assert r.dispatch(d, 10.0) == []  # resent: ignored
    # a busy robot queues an action only where its last held one ends, and only a later one
    with pytest.raises(SimRobotError, match=r"last held action ends on \(1, 0\)"):
        r.dispatch(Dispatch(0, 0, 1, (0, 0), (0, 1), 1000.0), 10.0)
    r.wake(1000.0)
    assert r.dispatch(d, 1000.0) == []  # the action just finished: a late duplicate
    assert r.state is RobotState.IDLE


def test_a_queue_runs_in_order_and_a_cancel_drops_the_tail() -> None:
    w = World([(0, 0), (3, 0)])
    r = SimRobot(0, w, (0, 0))
    a0 = Dispatch(0, 0, 0, (0, 0), (1, 0), 1000.0)
    a1 = Dispatch(0, 0, 1, (1, 0), (2, 0), 1000.0)
    a2 = Dispatch(0, 0, 2, (2, 0), (3, 0), 1000.0)  # (3, 0) is held by robot 1
    assert kinds(r.dispatch(a0, 0.0)) == [("started", 0.0)]
    assert r.dispatch(a1, 5.0) == [] and r.dispatch(a1, 6.0) == []  # queued; resend ignored
    assert r.queued == (a1,)
    with pytest.raises(SimRobotError, match="does not come after"):
        r.dispatch(Dispatch(-1, 0, 5, (2, 0), (3, 0), 1000.0), 7.0)  # an older plan's
    # a1 begins the instant a0 finishes (no round trip through the executor)
    assert [(e.kind, e.action, e.t_ms) for e in r.wake(1000.0)] == [
        ("finished", 0, 1000.0), ("started", 1, 1000.0)]
    assert r.dispatch(a2, 1200.0) == []
    assert [(e.kind, e.action) for e in r.wake(2000.0)] == [("finished", 1), ("blocked", 2)]
    assert [(e.kind, e.action) for e in r.cancel(0, 2, 2100.0)] == [("cancelled", 2)]
    assert r.state is RobotState.IDLE and r.cell == (2, 0)
    # a cancel of a queued action drops it and everything behind it; the current one runs on
    r2 = SimRobot(1, World([(0, 0), (5, 5)]), (5, 5))
    b = [Dispatch(0, 1, i, (5 + i, 5), (6 + i, 5), 100.0) for i in range(3)]
    for x in b:
        r2.dispatch(x, 0.0)
    assert [(e.kind, e.action) for e in r2.cancel(0, 1, 10.0)] == [
        ("cancelled", 1), ("cancelled", 2)]
    assert r2.cancel(0, 2, 10.0) == []  # already dropped: stale
    assert [(e.kind, e.action) for e in r2.wake(100.0)] == [("finished", 0)]
    assert r2.state is RobotState.IDLE and r2.queued == ()
