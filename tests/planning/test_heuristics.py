"""The planner's tables over the free cells: equal to a plain BFS, and, under ``turning``,
never above the exact turning cost they stand in for (an admissible lower bound)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from gateway.execution.lifelong.errands import TaskDistances
from gateway.planning.distance import cell_distance_rows, free_index, turning_distance_tables
from gateway.planning.generators import warehouse_map
from gateway.planning.grid import Grid
from gateway.planning.pibt import UNREACHABLE, StateSpace, WindowedPIBT, goal_tables
from tests.planning.test_cbs_low_level import bfs

grids = arrays(bool, st.tuples(st.integers(1, 9), st.integers(1, 9)), elements=st.booleans())


def _grid(free: np.ndarray) -> tuple[Grid, list[int]]:
    """The grid (one free cell at least) and its free cells' flat ids."""
    if not free.any():
        free[0, 0] = True
    grid = Grid(free)
    return grid, np.flatnonzero(grid.free.ravel()).tolist()


@settings(max_examples=60, deadline=None)
@given(grids, st.data())
def test_compact_rows_equal_breadth_first_search(free: np.ndarray, data: st.DataObject) -> None:
    grid, cells = _grid(free)
    goals = data.draw(st.lists(st.sampled_from(cells), min_size=1, max_size=8))
    rows = cell_distance_rows(grid, goals)
    index = free_index(grid)
    assert sorted(index[cells].tolist()) == list(range(len(cells)))
    for goal, row in zip(goals, rows, strict=True):
        want = bfs(grid, goal)
        assert row.tolist() == [want[c] for c in cells]


@st.composite
def grid_and_cell(draw: st.DrawFn) -> tuple[Grid, list[int], int]:
    """A drawn grid, its free cells and one of them."""
    grid, cells = _grid(draw(grids))
    return grid, cells, draw(st.sampled_from(cells))


@settings(max_examples=60, deadline=None)
@given(grid_and_cell())
def test_cell_tables_never_exceed_the_turning_cost(case: tuple[Grid, list[int], int]) -> None:
    grid, cells, goal = case
    exact = goal_tables(grid, True, [goal])[goal]
    lower = goal_tables(grid, False, [goal])[goal]
    assert list(exact) == np.where(
        (t := turning_distance_tables(grid, [grid.cell(goal)])[0]) < 0, UNREACHABLE, t).tolist()
    index = free_index(grid)
    for c in cells:
        for h in range(4):
            bound, cost = lower[index[c]], exact[4 * c + h]
            assert bound <= cost  # also: unreachable in one is unreachable in the other
            assert (bound == UNREACHABLE) == (cost == UNREACHABLE)
        assert (lower[index[c]] == 0) == (c == goal) == (min(exact[4 * c:4 * c + 4]) == 0)


@settings(max_examples=30, deadline=None)
@given(grid_and_cell(), st.integers(0, 3))
def test_each_option_is_weighed_by_its_cell_or_state(case: tuple[Grid, list[int], int],
                                                     h: int) -> None:
    grid, _, c = case
    exact, lower = StateSpace(grid, True, exact=True), StateSpace(grid, True, exact=False)
    assert exact.exact and not lower.exact
    index = free_index(grid)
    pairs = zip(exact.options[4 * c + h], lower.options[4 * c + h], strict=True)
    for (c1, e1, t1, s1), (c2, e2, t2, s2) in pairs:
        assert (c1, t1, s1) == (c2, t2, s2)
        assert e2 == index[c1] and e1 >> 2 == c1
    assert StateSpace(grid, False).options[c][0] == (c, index[c], 0, c)


@settings(max_examples=20, deadline=None)
@given(grid_and_cell(), st.data())
def test_the_scheduler_shares_the_planners_cell_tables(case: tuple[Grid, list[int], int],
                                                       data: st.DataObject) -> None:
    grid, cells, goal = case
    other = data.draw(st.sampled_from(cells))
    planner = StateSpace(grid, True, exact=False)
    shared = TaskDistances(grid, space=planner)
    assert shared.space is planner
    want = bfs(grid, goal)[other]
    assert shared.leg(goal, other) == (want if want >= 0 else UNREACHABLE)
    assert shared([other], [goal]).tolist() == [[want]]
    shared.charge, shared.charged = 5, {other}  # e.g. a robot in a delay there
    moves = bfs(grid, goal)
    expect = [[moves[c] + 5 * (c == other) if moves[c] >= 0 else -1] * 2
              for c in (other, goal, other)]
    assert shared([other, goal, other], [goal, goal]).tolist() == expect
    with pytest.raises(ValueError, match="only tables over the free cells"):
        TaskDistances(grid, space=StateSpace(grid, True, exact=True))


@pytest.mark.parametrize("exact", [True, False])
def test_a_robot_facing_away_turns_round_with_either_table(exact: bool) -> None:
    """A corridor 0-1-2-3, the robot on 0 facing west (away from its goal 3): it turns twice
    and drives on (with the cells' bound a wait looked as cheap as a turn: it waited forever)."""
    grid = Grid(np.ones((1, 4), dtype=bool))
    space = StateSpace(grid, True, exact=exact)
    win = WindowedPIBT(space, 1, seed=0).plan([space.state(0, 2)], [[3]], 6)
    assert [row[0] for row in win.states] == [2, 3, 0, 4, 8, 12, 12]  # cw, cw, 3 forward
    assert win.reached == [[5]]


def _compact(grid: Grid, turning: bool) -> StateSpace:
    """A space whose budget holds less than a table per robot of 2 bytes a cell: compact."""
    space = StateSpace(grid, turning, budget_bytes=64, robots=64, exact=False)
    assert space.compact
    return space


@settings(max_examples=40, deadline=None)
@given(grid_and_cell(), st.booleans())
def test_compact_tables_weigh_every_move_alike(case: tuple[Grid, list[int], int],
                                               turning: bool) -> None:
    """From the 2-bit table, each state's moves cost what they cost from the moves, shifted by
    one constant per state (so a robot ranks them alike), unreachable ones included."""
    grid, cells, goal = case
    plain, compact = StateSpace(grid, turning, exact=False), _compact(grid, turning)
    assert not plain.compact
    full, small = plain.distances(goal), compact.distances(goal)
    assert len(small) == (len(cells) + 3) // 4
    for c in cells:
        for s in ([4 * c + h for h in range(4)] if turning else [c]):
            want = plain.costs(full, plain.options[s])
            got = compact.costs(small, compact.options[s])
            if want[0] >= UNREACHABLE:
                assert all(g >= UNREACHABLE for g in got)
                continue
            shift = want[0] - got[0]
            assert [w - shift if w < UNREACHABLE else w for w in want] == got


@pytest.mark.parametrize("turning", [True, False])
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_compact_tables_plan_the_same_windows(turning: bool, seed: int) -> None:
    rng = np.random.default_rng(seed)
    grid = warehouse_map(4, 4, 6, shelf_depth=1, aisle=2, border=1)
    cells = np.flatnonzero(grid.free.ravel())
    n = 24
    starts = rng.choice(cells, size=n, replace=False).tolist()
    goals = [[int(g) for g in rng.choice(cells, size=2)] for _ in range(n)]
    windows = []
    for space in (StateSpace(grid, turning, exact=False), _compact(grid, turning)):
        planner = WindowedPIBT(space, n, seed=seed)
        windows.append(planner.plan([space.state(c) for c in starts], goals, 30))
    assert windows[0].states == windows[1].states and windows[0].reached == windows[1].reached
    assert any(windows[0].reached)  # robots got somewhere
