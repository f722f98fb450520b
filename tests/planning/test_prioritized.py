"""Prioritised planning: always valid 1-robust plans (never better than the optimum)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings

from gateway.planning.cbs import solve_cbs
from gateway.planning.distance import distance_table
from gateway.planning.grid import Cell, Grid
from gateway.planning.plan import NeverExpires, NoSolution
from gateway.planning.prioritized import solve_prioritized
from tests.planning.support_planning import (
    CountingDeadline,
    Forbidden,
    assert_valid,
    grid_of,
    small_instances,
)


@settings(max_examples=100, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(small_instances(6, 5, (2, 4)))
def test_prioritised_plans_are_valid_and_not_below_the_optimum(
    inst: tuple[Grid, list[Cell], list[Cell], list[Forbidden]],
) -> None:
    grid, starts, goals, forbidden = inst
    try:
        sol = solve_prioritized(grid, starts, goals, deadline=NeverExpires(),
                                forbidden=forbidden, attempts=5)
    except NoSolution:
        return  # prioritised planning is incomplete; validity is what it promises
    assert not sol.optimal
    assert_valid(grid, starts, goals, sol.plan, forbidden)
    best = solve_cbs(grid, starts, goals, deadline=NeverExpires(), forbidden=forbidden)
    assert sol.plan.soc >= best.plan.soc


def test_agent_boxed_in_by_a_goal_goes_first() -> None:
    # Pocket (1,1) under corridor cell (1,0). Agent 0 (3,0)->(1,0) and agent 1 (0,0)->(1,1)
    # both have distance 2; by distance alone agent 0 would go first and park on (1,0) (held
    # from t=1), sealing the pocket. Agent 1's goal is cut off by agent 0's goal, so it is
    # planned first and the first order succeeds.
    grid = grid_of("....", "@.@@")
    starts, goals = [(3, 0), (0, 0)], [(1, 0), (1, 1)]
    sol = solve_prioritized(grid, starts, goals, deadline=NeverExpires(), attempts=1)
    assert sol.expanded_nodes == 1  # attempts
    assert_valid(grid, starts, goals, sol.plan)


def test_gives_up_after_its_attempts() -> None:
    # A swap in a corridor: every order fails; each failure reorders and retries.
    with pytest.raises(NoSolution, match="in 4 orders") as err:
        solve_prioritized(grid_of("...."), [(0, 0), (3, 0)], [(3, 0), (0, 0)],
                          deadline=NeverExpires(), attempts=4)
    assert not err.value.timed_out


def test_many_agents_on_a_generated_map() -> None:
    rng = np.random.default_rng(7)
    free = rng.random((40, 40)) > 0.1
    free[:, ::8] = True  # open columns keep the map in one piece
    free[::8, :] = True
    grid = Grid(free)
    reach = distance_table(grid, (0, 0))
    cells = [c for c in grid.free_cells() if reach[grid.index(c)] >= 0]
    pick = rng.permutation(len(cells))
    starts = [cells[i] for i in pick[:120]]
    goals = [cells[i] for i in pick[120:240]]
    sol = solve_prioritized(grid, starts, goals, deadline=NeverExpires())
    assert_valid(grid, starts, goals, sol.plan)


def test_deadline_expiry_raises_timed_out() -> None:
    grid = grid_of("......", "......")
    with pytest.raises(NoSolution) as err:
        solve_prioritized(grid, [(0, 0)], [(5, 1)], deadline=CountingDeadline(0))
    assert err.value.timed_out
