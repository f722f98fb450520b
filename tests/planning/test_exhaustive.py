"""The exhaustive joint-state oracle on hand-solved instances (so that it can be trusted)."""

from __future__ import annotations

from tests.planning.exhaustive import optimal_soc
from tests.planning.support_planning import grid_of


def test_following_costs_a_step() -> None:
    # 4x1 corridor, A (0,0)->(2,0), B (1,0)->(3,0). B moves at t=1; A may not enter (1,0) at
    # t=1 (B was there at t=0), so it enters at t=2 and reaches (2,0) at t=3: 3 + 2 = 5.
    assert optimal_soc(grid_of("...."), [(0, 0), (1, 0)], [(2, 0), (3, 0)]) == 5


def test_agent_on_goal_steps_aside_and_pays_its_return() -> None:
    # A sits on its goal (1,0) above a pocket; B crosses (0,0)->(2,0). A dodges at t=1, B
    # enters (1,0) at t=2 (not t=1: A was there at t=0), leaves at t=3; A may re-enter only
    # at t=4 (B was there at t=2... and t=3 is B's departure step). Costs B 3 + A 4 = 7.
    grid = grid_of("...", "@.@")
    assert optimal_soc(grid, [(1, 0), (0, 0)], [(1, 0), (2, 0)]) == 7


def test_swap_in_a_corridor_is_impossible() -> None:
    assert optimal_soc(grid_of("..."), [(0, 0), (2, 0)], [(2, 0), (0, 0)], max_cost=20) is None


def test_passing_over_the_goal_counts_only_the_last_arrival() -> None:
    # One agent costs its distance; a forbidden window on its goal at t=1..2 makes it arrive
    # at t=3 (passing through earlier is impossible here, so it waits).
    grid = grid_of("...")
    assert optimal_soc(grid, [(0, 0)], [(1, 0)]) == 1
    assert optimal_soc(grid, [(0, 0)], [(1, 0)], forbidden=[((1, 0), 1, 2)]) == 3
    # Starting on its goal, closed at t=2..4: it must leave and come back at t=5; the stay at
    # the start and the detour do not count, only the final arrival (cost 5).
    assert optimal_soc(grid, [(1, 0)], [(1, 0)], forbidden=[((1, 0), 2, 4)]) == 5


def test_forbidden_start_has_no_plan() -> None:
    assert optimal_soc(grid_of("..."), [(0, 0)], [(2, 0)], forbidden=[((0, 0), 0, 0)]) is None
