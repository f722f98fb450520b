"""Reported blocks: the tracker's estimates by hand, and the executor opening, clearing and
handing them to an informed replan (never the simulator's ground truth)."""

from __future__ import annotations

import pytest

from gateway.execution.commands import Dispatch, SolveRequest
from gateway.execution.oneshot.adg import gated_waits
from gateway.execution.oneshot.blocks import BlockTracker
from gateway.execution.oneshot.executor import Executor
from gateway.planning.plan import Plan


def test_estimates_by_hand() -> None:
    b = BlockTracker(min_ms=1000.0)
    b.opened((1, 1), 5000.0)
    # Nothing earlier: a block seen for e lasts 2e in all, never under one action.
    assert b.expected_end_ms((1, 1)) == 6000.0
    b.still_blocked((1, 1), 5400.0)
    assert b.expected_end_ms((1, 1)) == 6000.0
    b.still_blocked((1, 1), 7000.0)
    assert b.expected_end_ms((1, 1)) == 9000.0
    # Nobody looks any more: the estimate stays; past its end it is no obstacle.
    assert b.obstacles(8999.0) == (((1, 1), 9000.0),) and b.obstacles(9000.0) == ()
    b.opened((1, 1), 7500.0)  # a second report keeps the first start
    assert b.expected_end_ms((1, 1)) == 10_000.0
    b.cleared((1, 1), 8000.0)
    assert b.history == [3000.0] and not b.open and not b.seen
    b.cleared((1, 1), 9000.0)  # nothing open there: nothing to remember
    b.still_blocked((1, 1), 9000.0)
    assert b.history == [3000.0] and not b.seen
    b.opened((2, 2), 10_000.0)
    b.history.append(7000.0)
    # Seen for 1000: the earlier blocks that lasted longer (3000, 7000) average 5000.
    b.still_blocked((2, 2), 11_000.0)
    assert b.expected_end_ms((2, 2)) == 15_000.0
    # Seen for 4000: only the 7000 one lasted longer.
    b.still_blocked((2, 2), 14_000.0)
    assert b.expected_end_ms((2, 2)) == 17_000.0
    # Seen for 8000, longer than any earlier: 2e, a guess no earlier block supports.
    b.still_blocked((2, 2), 18_000.0)
    assert b.expected_end_ms((2, 2)) == 26_000.0


def _two_robots() -> Plan:
    # Robot 0 drives (0,0) -> (2,0); robot 1 waits on (4,4) then goes to (4,3).
    return Plan((((0, 0), (1, 0), (2, 0)), ((4, 4), (4, 4), (4, 3))))


@pytest.mark.parametrize("informed", [False, True])
def test_a_block_with_no_planned_occupant_goes_to_an_informed_replan(informed: bool) -> None:
    ex = Executor(_two_robots(), informed=informed)
    ex.start(0.0)
    ex.drain()
    ex.blocked(0, 0, 0, 0.0)  # (1,0) is taken by something no plan knows
    ex.started(1, 0, 0, 0.0)
    assert ex.blocks.open == {(1, 0): 0.0}
    ex.tick(2000.0)
    ex.request_replan(2000.0)
    cmds = ex.drain()
    ex.cancelled(0, 0, 0, 2000.0)
    ex.finished(1, 0, 0, 2000.0)
    req = [c for c in [*cmds, *ex.drain()] if isinstance(c, SolveRequest)]
    assert len(req) == 1
    # Lasted 2000 ms, nothing earlier: expected to clear at 4000 ms.
    assert req[0].obstacles == ((((1, 0), 4000.0),) if informed else ())
    # Nobody waits for (1,0) any more: the estimate no longer grows with time.
    ex.tick(3000.0)
    assert ex.blocks.open == {(1, 0): 0.0} and ex.blocks.expected_end_ms((1, 0)) == 4000.0


def test_a_robot_moving_in_clears_the_block_and_a_held_cell_is_no_block() -> None:
    ex = Executor(Plan((((0, 0), (1, 0), (2, 0)), ((3, 0), (3, 0), (2, 0)))), informed=True)
    ex.start(0.0)
    ex.drain()
    ex.blocked(0, 0, 0, 0.0)
    ex.unblocked(0, 0, 0, 500.0)
    ex.started(0, 0, 0, 500.0)
    assert ex.blocks.history == [500.0] and not ex.blocks.open
    ex.finished(0, 0, 0, 1500.0)
    # Robot 0 stands on (1,0): a robot waiting for it there waits for a planned occupant (the
    # ADG makes that impossible in a valid run, so this is checked on the helper).
    assert ex._planned_occupant((1, 0), 1) and not ex._planned_occupant((1, 0), 0)


def test_gated_waits_by_hand() -> None:
    plan = Plan((((0, 0), (0, 0), (0, 0), (1, 0), (2, 0)),   # waits twice, enters (1,0)
                 ((0, 1), (0, 1), (1, 1), (1, 1), (1, 0)),   # waits for (1,1); then (1,0)
                 ((3, 3), (3, 3), (3, 3))))                  # only waits
    assert gated_waits(plan, {(1, 0)}) == {(0, 0), (0, 1), (1, 2)}
    assert gated_waits(plan, {(1, 1)}) == {(1, 0)}
    assert gated_waits(plan, ()) == frozenset()
    # Turning: a turn before the move ends the run of waits (only the wait after it gates).
    turning = Plan((((0, 0), (0, 0), (0, 0), (0, 0), (1, 0)),), ((1, 1, 0, 0, 0),))
    assert gated_waits(turning, {(1, 0)}) == {(0, 2)}


def test_an_informed_replan_moves_in_when_the_block_ends_not_when_expected() -> None:
    ex = Executor(_two_robots(), informed=True)
    ex.start(0.0)
    ex.drain()
    ex.blocked(0, 0, 0, 0.0)
    ex.started(1, 0, 0, 0.0)
    ex.tick(2000.0)
    ex.request_replan(2000.0)
    ex.drain()
    ex.cancelled(0, 0, 0, 2000.0)
    ex.finished(1, 0, 0, 2000.0)
    ex.drain()
    # The planner kept (1,0) free until 4000 ms: robot 0 waits twice on (0,0), then drives.
    ex.adopt_plan(Plan((((0, 0), (0, 0), (0, 0), (1, 0), (2, 0)), ((4, 4), (4, 3)))), 2000.0)
    dispatch, _ = sorted((c for c in ex.drain() if isinstance(c, Dispatch)),
                         key=lambda c: c.robot)
    # The waits are gone: the move into (1,0) is dispatched at once and starts when the
    # cell is free (here at 2500 ms, before the expected 4000 ms).
    assert (dispatch.robot, dispatch.action, dispatch.dst) == (0, 2, (1, 0))
    ex.started(1, 1, 0, 2000.0)
    ex.blocked(0, 1, 2, 2000.0)
    ex.unblocked(0, 1, 2, 2500.0)
    ex.started(0, 1, 2, 2500.0)
    ex.finished(1, 1, 0, 3000.0)
    ex.finished(0, 1, 2, 3500.0)
    ex.drain()
    ex.started(0, 1, 3, 3500.0)
    ex.finished(0, 1, 3, 4500.0)
    assert ex.done and ex.completions_ms[0] == 4500.0
    assert ex.blocks.history == [2500.0]  # the block is watched to its end


def test_an_uninformed_replan_keeps_its_waits() -> None:
    ex = Executor(_two_robots())
    ex.start(0.0)
    ex.drain()
    ex.blocked(0, 0, 0, 0.0)
    ex.started(1, 0, 0, 0.0)
    ex.request_replan(1000.0)
    ex.drain()
    ex.cancelled(0, 0, 0, 1000.0)
    ex.finished(1, 0, 0, 1000.0)
    ex.drain()
    ex.adopt_plan(Plan((((0, 0), (0, 0), (1, 0), (2, 0)), ((4, 4), (4, 3)))), 1000.0)
    dispatch, _ = sorted((c for c in ex.drain() if isinstance(c, Dispatch)),
                         key=lambda c: c.robot)
    assert (dispatch.action, dispatch.dst) == (0, (0, 0))
