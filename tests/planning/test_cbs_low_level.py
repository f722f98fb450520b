"""The planner's building blocks: distance tables, constraint tables, space-time A*, MDDs and
the rectangle geometry."""

from __future__ import annotations

from collections import deque

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from gateway.planning.cbs_conflicts import pair_conflicts, rectangle
from gateway.planning.constraints import FINISH, INF, build_table
from gateway.planning.distance import distance_table, distance_tables
from gateway.planning.grid import Grid
from gateway.planning.low_level import OmniModel, build_mdd, mdd_always_visits, space_time_astar
from gateway.planning.plan import NeverExpires
from tests.planning.support_planning import grid_of


def bfs(grid: Grid, source: int) -> list[int]:
    """Textbook breadth-first search over Grid.neighbour_ids (the oracle)."""
    dist = [-1] * grid.size
    dist[source] = 0
    queue = deque([source])
    while queue:
        u = queue.popleft()
        for v in grid.neighbour_ids(u):
            if dist[v] < 0:
                dist[v] = dist[u] + 1
                queue.append(v)
    return dist


@settings(max_examples=60, deadline=None)
@given(arrays(bool, st.tuples(st.integers(1, 9), st.integers(1, 9)), elements=st.booleans()),
       st.data())
def test_distance_tables_match_breadth_first_search(free: np.ndarray, data: st.DataObject) -> None:
    if not free.any():
        free[0, 0] = True
    grid = Grid(free)
    cells = list(grid.free_cells())
    goals = data.draw(st.lists(st.sampled_from(cells), min_size=1, max_size=70))
    tables = distance_tables(grid, goals)  # more than one chunk when > 64 goals
    for goal, row in zip(goals, tables, strict=True):
        assert row.tolist() == bfs(grid, grid.index(goal))
    assert distance_table(grid, goals[0]).tolist() == bfs(grid, grid.index(goals[0]))


def test_distance_table_rejects_a_blocked_goal() -> None:
    with pytest.raises(ValueError, match="not a free cell"):
        distance_table(grid_of(".@."), (1, 0))


def test_constraint_table_goal_block_and_finish() -> None:
    table = build_table(10, [(3, 2, 4), (5, 1, INF), (FINISH, 6, 6)])
    assert table.forbids(3, 2) and table.forbids(3, 4) and not table.forbids(3, 5)
    assert table.forbids(5, 100) and not table.forbids(5, 0)
    assert table.goal_block(3) == 6  # the finish constraint dominates the window's end 4
    assert table.goal_block(5) == INF
    assert table.goal_block(7) == 6
    with pytest.raises(ValueError, match="bad time range"):
        build_table(10, [(3, 4, 2)])


def plan_one(
    grid: Grid, start: int, goal: int, constraints: list[tuple[int, int, int]]
) -> list[int] | None:
    model = OmniModel(grid)
    h = model.heuristics([goal])[0]
    return space_time_astar(model, start, goal, h, build_table(grid.size, constraints), None,
                            NeverExpires())


def test_finish_constraint_still_lets_the_agent_cross_its_goal() -> None:
    # Corridor 0-1-2-3, goal 2 (start 0). Not finishing before t=5 costs 5 (not 2): it may
    # reach 2 at t=2 and move on, as long as its last arrival is at t >= 5.
    path = plan_one(grid_of("...."), 0, 2, [(FINISH, 4, 4)])
    assert path is not None and len(path) - 1 == 5 and path[-1] == 2
    # A window on the goal itself forbids being there at all during it.
    path = plan_one(grid_of("...."), 0, 2, [(2, 1, 4)])
    assert path is not None and len(path) - 1 == 5 and 2 not in path[1:5]


def test_low_level_reports_no_path_and_permanent_blocks() -> None:
    assert plan_one(grid_of("..."), 0, 2, [(1, 0, INF)]) is None
    assert plan_one(grid_of("..."), 0, 2, [(2, 3, INF)]) is None  # goal closed for ever


def test_mdd_always_visits() -> None:
    grid = grid_of("...", ".@.")
    model = OmniModel(grid)
    h = model.heuristics([2])[0]
    table = build_table(grid.size, [])
    mdd = build_mdd(model, 0, h, table, 2)  # the only 2-step path is 0, 1, 2
    assert [sorted(layer) for layer in mdd] == [[0], [1], [2]]
    assert mdd_always_visits(model, mdd, 2, 1, 1, 1)
    assert not mdd_always_visits(model, mdd, 2, 1, 2, 3)
    assert mdd_always_visits(model, mdd, 2, 2, 5, 9)  # parked on the goal after t=2


def test_pair_conflicts_kinds() -> None:
    # On a line: i goes 0, 1, 2 and parks on 2 from t=2; j goes 5, 4, 3, 2, 1 and is on 2 at
    # t=3: a target conflict (i finishes after 4, or j keeps off 2 from t=3).
    pi = (0, 1, 2)
    pj = (5, 4, 3, 2, 1)
    found = pair_conflicts(0, pi, 1, pj, target=True)
    targets = [c for c in found if c[1][1][0][0] == FINISH]
    assert targets == [(3, (0, ((FINISH, 4, 4),)), (1, ((2, 3, INF),)))]
    plain = pair_conflicts(0, pi, 1, pj, target=False)
    assert plain and all(c[1][1][0][0] != FINISH for c in plain)
    assert pair_conflicts(0, (0, 1), 1, (7, 8), target=True) == []


def test_rectangle_geometry() -> None:
    # Both move right/down on a 6-wide grid: i (0,1)->(5,4), j (1,0)->(4,5); delta = 0.
    got = rectangle(0, (0, 1), (5, 4), 1, (1, 0), (4, 5), 6)
    assert got is not None
    (h, bar_h), (v, bar_v) = got
    assert (h, v) == (0, 1)
    # i's barrier: exit column x = 4 for y = 1..4 at tau = 4 + (y - 1), widened by 1.
    assert bar_h == tuple((y * 6 + 4, 4 + y - 1, 4 + y) for y in range(1, 5))
    # j's barrier: exit row y = 4 for x = 1..4 at tau = (x - 1) + 4, widened by 1.
    assert bar_v == tuple((4 * 6 + x, x - 1 + 4, x + 4) for x in range(1, 5))
    # i one step ahead (delta = -1): i's range keeps its slack, j's has none.
    got = rectangle(0, (0, 2), (5, 4), 1, (1, 0), (4, 5), 6)
    assert got is not None
    assert all(t1 == t0 + 1 for _, t0, t1 in got[0][1])
    assert all(t1 == t0 for _, t0, t1 in got[1][1])
    # Opposite directions, or offsets of 2 steps, are no rectangle.
    assert rectangle(0, (0, 1), (5, 4), 1, (4, 5), (1, 0), 6) is None
    assert rectangle(0, (0, 3), (5, 4), 1, (1, 0), (4, 5), 6) is None
