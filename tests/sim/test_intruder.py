"""The intruder: target choice (DESIGN section 2) and its life on the World."""

from __future__ import annotations

import random

import pytest

from gateway.planning.plan import Plan
from gateway.planning.random_plans import open_grid
from sim_clients.des import SimConfig, run_simulation
from sim_clients.intruder import Intruder, IntruderConfig, IntruderState, pick_target
from sim_clients.world import INTRUDER, World

# robot 0 waits then moves right along y=0; robot 1 has only waits left; robot 2 moves down
PATHS = (
    ((0, 0), (0, 0), (1, 0), (2, 0), (3, 0)),
    ((5, 5), (5, 5)),
    ((7, 0), (7, 1), (7, 2)),
)


def est(robot: int, action: int) -> float:
    """Estimated start of a_action: 1000 ms per step (as on an undelayed plan)."""
    return 1000.0 * action


def test_first_move_starting_at_or_after_the_lead() -> None:
    # robot 0's moves start at 1000 (a1), 2000 (a2), 3000 (a3); with not_before 2000 the
    # first one is a2 = (1,0)->(2,0), so the intruder goes for (2,0)
    rng = random.Random(0)
    seen = {pick_target(rng, PATHS, [0, 0, 0], est, 2000.0) for _ in range(50)}
    # robot 1 has no move: never chosen; robot 2's moves start at 0 and 1000: both too early,
    # so its last move's cell (7,2) is taken
    assert seen == {(0, (2, 0)), (2, (7, 2))}


def test_started_actions_are_behind_the_robot() -> None:
    rng = random.Random(1)
    # robot 0 already started a3 (next_action 4): no move ahead; robot 2 is done
    assert pick_target(rng, PATHS, [4, 0, 2], est, 0.0) is None
    # robot 0 has started a1: its next move not started is a2
    assert pick_target(rng, PATHS, [2, 0, 2], est, 0.0) == (0, (2, 0))


def test_same_seed_same_choice() -> None:
    picks = [pick_target(random.Random(7), PATHS, [0, 0, 0], est, 2000.0) for _ in range(3)]
    assert picks[0] == picks[1] == picks[2]


def test_enters_free_cell_at_once_and_leaves_at_leave_time() -> None:
    w = World([(0, 0)])
    intr = Intruder(w, IntruderConfig(appear_ms=3000, leave_ms=10000))
    assert intr.next_wakeup_ms() == 3000
    events = intr.appear(3000, (0, (2, 0)))
    assert [(e.t_ms, e.cell, e.state) for e in events] == [(3000, (2, 0), "on")]
    assert w.holders((2, 0)) == (INTRUDER,) and intr.next_wakeup_ms() == 10000
    assert intr.wake(9999) == []
    assert [(e.t_ms, e.state) for e in intr.wake(10000)] == [(10000, "off")]
    assert w.is_free((2, 0)) and intr.state is IntruderState.GONE
    assert intr.next_wakeup_ms() is None


def test_waits_for_a_taken_cell_polling_every_100ms() -> None:
    w = World([(2, 0)])
    intr = Intruder(w)
    assert intr.appear(3000, (1, (2, 0))) == []
    assert intr.state is IntruderState.WAITING and intr.next_wakeup_ms() == 3100
    assert intr.wake(3100) == [] and intr.next_wakeup_ms() == 3200
    w.release((2, 0), 0)
    assert [(e.t_ms, e.state) for e in intr.wake(3200)] == [(3200, "on")]
    assert intr.entered_ms == 3200


def test_never_enters_if_the_cell_stays_taken() -> None:
    w = World([(2, 0)])
    intr = Intruder(w, IntruderConfig(appear_ms=3000, leave_ms=3250))
    intr.appear(3000, (0, (2, 0)))
    t = intr.next_wakeup_ms()
    while t is not None:
        assert intr.wake(t) == []
        t = intr.next_wakeup_ms()
    assert intr.state is IntruderState.GONE and intr.entered_ms is None
    assert w.holders((2, 0)) == (0,)


def test_no_target_means_no_intruder_and_bad_config_is_refused() -> None:
    intr = Intruder(World())
    assert intr.appear(3000, None) == [] and intr.state is IntruderState.GONE
    with pytest.raises(ValueError, match="already appeared"):
        intr.appear(3000, None)
    with pytest.raises(ValueError, match="appear_ms < leave_ms"):
        IntruderConfig(appear_ms=5000, leave_ms=4000)


@pytest.mark.parametrize(("reading", "cell"), [("start", (6, 0)), ("arrival", (5, 0))])
def test_the_reading_of_visit_at_t_a_plus_2_s(reading: str, cell: tuple[int, int]) -> None:
    # One robot drives along y=0 from (0,0), one cell per 1000 ms: the move into (k+1,0) starts
    # at k*1000 and arrives at (k+1)*1000. T_a + 2 s = 5000: the first move STARTING then goes
    # into (6,0), the first one ARRIVING then into (5,0). The intruder sits there until 9000 ms.
    grid = open_grid(10, 1)
    plan = Plan((tuple((x, 0) for x in range(10)),))
    res = run_simulation(SimConfig(
        grid=grid, plan=plan, solver_time="zero", intruder_config=IntruderConfig(
            appear_ms=3000, leave_ms=9000, reading=reading)))  # type: ignore[arg-type]
    assert (res.intruder_robot, res.intruder_cell, res.intruder_on_ms) == (0, cell, 3000)
    # The robot finds the cell taken at (x - 1) * 1000 and looks again every 100 ms; at 9000
    # its look comes before the intruder leaves (events at one instant: robots first), so it
    # sets off at 9100 and has 10 - x moves of 1000 ms left.
    assert res.soc_ms == 9100 + (10 - cell[0]) * 1000


def test_an_unknown_reading_is_refused() -> None:
    with pytest.raises(ValueError, match="reading must be one of start, arrival"):
        IntruderConfig(reading="never")  # type: ignore[arg-type]
