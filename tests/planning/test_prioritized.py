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


def test_failed_agent_moves_to_the_front() -> None:
    # Pocket (1,1) under corridor cell (1,0). Agent 0 (3,0)->(1,0) and agent 1 (0,0)->(1,1)
    # both have distance 2, so agent 0 goes first and parks on (1,0) from t=2, which holds the
    # cell from t=1: agent 1 can never pass. The restart plans agent 1 first and succeeds.
    grid = grid_of("....", "@.@@")
    starts, goals = [(3, 0), (0, 0)], [(1, 0), (1, 1)]
    sol = solve_prioritized(grid, starts, goals, deadline=NeverExpires())
    assert sol.expanded_nodes == 2  # attempts
    assert_valid(grid, starts, goals, sol.plan)
    with pytest.raises(NoSolution) as err:
        solve_prioritized(grid, starts, goals, deadline=NeverExpires(), attempts=1)
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
