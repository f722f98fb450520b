"""Guided tables (crisscross lanes): equal to a textbook Dijkstra over the turning states,
twice the exact timesteps without a penalty, and the planner's option costs consistent with
them."""

from __future__ import annotations

import heapq

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from gateway.planning.distance import cell_distance_rows, turning_distance_tables
from gateway.planning.grid import Grid
from gateway.planning.guidance import (
    CROWD_AGE,
    CROWD_WEIGHT,
    DOOR_ROOM,
    MOVE,
    corridor_lanes,
    crisscross,
    crowd,
    crowded,
    door_cells,
    guided_cell_tables,
    guided_tables,
    one_way_doors,
)
from gateway.planning.pibt import UNREACHABLE, StateSpace

grids = arrays(bool, st.tuples(st.integers(1, 8), st.integers(1, 8)), elements=st.booleans())
STEP = ((1, 0), (0, 1), (-1, 0), (0, -1))  # headings east, south, west, north


@st.composite
def grid_and_goal(draw: st.DrawFn) -> tuple[Grid, int]:
    """A drawn grid (one free cell at least) and one of its free cells."""
    free = draw(grids)
    if not free.any():
        free[0, 0] = True
    grid = Grid(free)
    return grid, draw(st.sampled_from(np.flatnonzero(grid.free.ravel()).tolist()))


def dijkstra(grid: Grid, goal: int, forward: list[int], turn: int = MOVE) -> list[int]:
    """Textbook forward Dijkstra from every state to the goal cell (the oracle): a turn costs
    ``turn``, a forward move out of state s ``forward[s]``; -1 if unreachable."""
    w, h = grid.width, grid.height
    out = []
    for start in range(4 * grid.size):
        c = start >> 2
        if not grid.free.ravel()[c]:
            out.append(-1)
            continue
        best = {start: 0}
        heap = [(0, start)]
        found = -1
        while heap:
            d, s = heapq.heappop(heap)
            if d > best[s]:
                continue
            if s >> 2 == goal:
                found = d
                break
            c, hd = s >> 2, s & 3
            x, y = c % w, c // w
            nxt = [(4 * c + (hd + 1) % 4, turn), (4 * c + (hd + 3) % 4, turn)]
            nx, ny = x + STEP[hd][0], y + STEP[hd][1]
            if 0 <= nx < w and 0 <= ny < h and grid.free[ny, nx]:
                nxt.append((4 * (ny * w + nx) + hd, forward[s]))
            for u, cost in nxt:
                if d + cost < best.get(u, 1 << 30):
                    best[u] = d + cost
                    heapq.heappush(heap, (d + cost, u))
        out.append(found)
    return out


def test_crisscross_lanes_by_hand() -> None:
    """Even rows east, odd rows west, even columns south, odd columns north."""
    grid = Grid(np.ones((2, 2), dtype=bool))
    lanes = crisscross(grid, 3).reshape(4, 4).tolist()
    assert lanes[0] == [2, 2, 5, 5]  # (0, 0): east and south along
    assert lanes[3] == [5, 5, 2, 2]  # (1, 1): west and north along
    assert lanes[1] == [2, 5, 5, 2]  # (1, 0): east, north
    with pytest.raises(ValueError, match="at least 0"):
        crisscross(grid, -1)


@settings(max_examples=40, deadline=None)
@given(grid_and_goal(), st.integers(0, 5))
def test_guided_tables_equal_a_textbook_dijkstra(case: tuple[Grid, int], penalty: int) -> None:
    grid, goal = case
    forward = crisscross(grid, penalty)
    got = guided_tables(grid, [goal], forward)[0].tolist()
    assert got == dijkstra(grid, goal, forward.tolist())
    steps = turning_distance_tables(grid, [grid.cell(goal)])[0]
    if penalty == 0:
        assert got == np.where(steps < 0, -1, MOVE * steps).tolist()
    for cost, exact in zip(got, steps.tolist(), strict=True):  # lanes only lengthen a path
        assert (cost < 0) == (exact < 0)
        if exact >= 0:
            assert MOVE * exact <= cost <= (MOVE + penalty) * exact


@settings(max_examples=40, deadline=None)
@given(grid_and_goal(), st.integers(0, 5), st.sampled_from([MOVE, 3, 6]))
def test_dearer_turns_equal_a_textbook_dijkstra(case: tuple[Grid, int], penalty: int,
                                                turn: int) -> None:
    """With a turn costing more than a move: the textbook Dijkstra's costs, between the
    costs with turns of one move and those with every action costing the turn."""
    grid, goal = case
    forward = crisscross(grid, penalty)
    got = guided_tables(grid, [goal], forward, turn)[0].tolist()
    assert got == dijkstra(grid, goal, forward.tolist(), turn)
    low = guided_tables(grid, [goal], forward)[0].tolist()
    high = guided_tables(grid, [goal], forward + (turn - MOVE), turn)[0].tolist()
    for a, b, c in zip(low, got, high, strict=True):
        assert (a < 0) == (b < 0) == (c < 0)
        assert a <= b <= c


@settings(max_examples=40, deadline=None)
@given(grid_and_goal(), st.integers(1, 4), st.sampled_from([MOVE, 6]))
def test_the_best_option_costs_the_table_entry(case: tuple[Grid, int], penalty: int,
                                               turn: int) -> None:
    """From every state off the goal that can reach it, the cheapest move (forward, or a turn
    towards a cell) costs exactly the state's table entry (Bellman), none less, and waiting
    costs one MOVE more; with turns costing more too."""
    grid, goal = case
    space = StateSpace(grid, True, exact=True, guidance=crisscross(grid, penalty), turn=turn)
    table = space.distances(goal)
    for s in range(space.n_states):
        opts = space.options[s]
        if not opts or table[s] in (0, UNREACHABLE):
            continue
        costs = space.costs(table, opts)
        assert costs[0] == table[s] + MOVE
        assert min(costs[1:]) == table[s]


def two_rooms(width: int, height: int, doors: list[int]) -> Grid:
    """Two rooms of ``width`` x ``height`` cells, one above the other, split by a wall row
    with one-cell doors at the columns ``doors``."""
    free = np.ones((2 * height + 1, width), dtype=bool)
    free[height] = False
    free[height, doors] = True
    return Grid(free)


def test_two_doors_between_two_rooms_run_opposite_ways_by_hand() -> None:
    """9 x 4 rooms (36 cells each), doors in columns 2 and 6 of wall row 4: the first door
    runs south (a move north into it, or on through it, costs the penalty more), the second
    north; nothing else costs more."""
    grid = two_rooms(9, 4, [2, 6])
    w = grid.width
    assert door_cells(grid) == [(4 * w + 2, 0), (4 * w + 6, 0)]
    extra = one_way_doors(grid, 7)
    north, south = 3, 1
    want = {4 * (5 * w + 2) + north, 4 * (4 * w + 2) + north,
            4 * (3 * w + 6) + south, 4 * (4 * w + 6) + south}
    assert set(np.flatnonzero(extra).tolist()) == want
    assert (extra[list(want)] == 7).all()
    assert not one_way_doors(grid, 0).any()
    with pytest.raises(ValueError, match="at least 0"):
        one_way_doors(grid, -1)


def test_a_lone_door_or_a_pocket_is_not_made_one_way() -> None:
    """A single door between two rooms, or two into a pocket of fewer than DOOR_ROOM cells:
    both ways cost the same."""
    assert not one_way_doors(two_rooms(9, 4, [4]), 5).any()
    pocket = two_rooms(3, 2, [0, 2])  # rooms of 6 cells
    assert len(door_cells(pocket)) == 2 and DOOR_ROOM > 6
    assert not one_way_doors(pocket, 5).any()


@st.composite
def rooms_and_goal(draw: st.DrawFn) -> tuple[Grid, int]:
    """Two rooms split by a wall row with drawn doors, a few drawn obstacles, and a goal."""
    width, height = draw(st.integers(4, 9)), draw(st.integers(3, 5))  # 12-45 cells a room
    doors = draw(st.lists(st.integers(0, width - 1), min_size=2, max_size=4, unique=True))
    grid = two_rooms(width, height, sorted(doors))
    free = grid.free.copy()
    for y, x in draw(st.lists(st.tuples(st.integers(0, 2 * height), st.integers(0, width - 1)),
                              max_size=3)):
        free[y, x] = False
    grid = Grid(free)
    cells = np.flatnonzero(grid.free.ravel()).tolist()
    if not cells:
        grid = Grid(np.ones((1, 1), dtype=bool))
        cells = [0]
    return grid, draw(st.sampled_from(cells))


@settings(max_examples=80, deadline=None)
@given(rooms_and_goal(), st.integers(1, 30))
def test_one_way_doors_cost_only_against_a_door(case: tuple[Grid, int], penalty: int) -> None:
    """Only moves into a door along its passage, or on through it, cost more, by the penalty,
    and each door costs more one way at most; the tables under lanes plus doors equal the
    textbook Dijkstra's, and doors only lengthen a path."""
    grid, goal = case
    extra = one_way_doors(grid, penalty)
    w = grid.width
    doors = dict(door_cells(grid))
    against: dict[int, set[int]] = {}
    for s in np.flatnonzero(extra).tolist():
        assert extra[s] == penalty
        c, heading = s >> 2, s & 3
        step = (1, w, -1, -w)[heading]
        door = c if c in doors else c + step
        assert door in doors and (heading % 2 == 1) == (doors[door] == 0)
        against.setdefault(door, set()).add(heading)
    assert all(len(h) == 1 for h in against.values())
    forward = crisscross(grid, 2) + extra
    got = guided_tables(grid, [goal], forward)[0].tolist()
    assert got == dijkstra(grid, goal, forward.tolist())
    lanes = guided_tables(grid, [goal], crisscross(grid, 2))[0].tolist()
    assert all((a < 0) == (b < 0) and a <= b for a, b in zip(lanes, got, strict=True))


def test_guidance_needs_the_turning_model_and_tables_of_costs() -> None:
    grid = Grid(np.ones((3, 3), dtype=bool))
    with pytest.raises(ValueError, match="turning model"):
        StateSpace(grid, False, guidance=crisscross(grid, 1))
    with pytest.raises(ValueError, match="not compact"):  # 2 bytes x 9 cells x 100 > 1,000
        StateSpace(grid, True, budget_bytes=1000, robots=100, exact=False,
                   guidance=crisscross(grid, 1))
    with pytest.raises(ValueError, match="guidance of 4 states"):
        guided_tables(grid, [0], np.full(4, MOVE, dtype=np.int32))
    with pytest.raises(ValueError, match="turn must cost at least 2, not 1"):
        guided_tables(grid, [0], crisscross(grid, 0), 1)
    with pytest.raises(ValueError, match="not a free cell"):
        guided_tables(Grid(np.array([[True, False]])), [1], crisscross(grid, 0)[:8])


def test_the_crowd_counts_the_robots_in_each_cells_box() -> None:
    grid = Grid(np.ones((3, 3), dtype=bool))
    assert crowd(grid, [0, 2, 6, 8]).tolist() == [1, 2, 1,  # robots on the four corners
                                                  2, 4, 2,
                                                  1, 2, 1]


def test_a_move_costs_more_for_each_robot_around_the_cell_it_enters() -> None:
    grid = Grid(np.ones((3, 3), dtype=bool))
    forward = crowded(grid, crisscross(grid, 0), [0, 2, 6, 8])
    east, west, north = 0, 2, 3
    assert forward[4 * 0 + east] == MOVE + 2 * CROWD_WEIGHT  # into cell 1: two robots around
    assert forward[4 * 4 + north] == MOVE + 2 * CROWD_WEIGHT  # from the centre into cell 1
    assert forward[4 * 1 + east] == MOVE + 1 * CROWD_WEIGHT  # into the corner cell 2
    assert forward[4 * 0 + west] == MOVE  # off the map: no move, the lane's cost


def test_tables_are_searched_again_with_the_crowd_once_old() -> None:
    grid = Grid(np.ones((1, 5), dtype=bool))  # a corridor, the goal at its east end
    space = StateSpace(grid, True, exact=True, guidance=crisscross(grid, 0))
    goal, east = 4, 0
    assert space.distances(goal)[4 * 0 + east] == 4 * MOVE
    for _ in range(CROWD_AGE - 1):  # a robot on x=2: cells 1-3 cost more to enter
        space.guide([2], [goal])
        assert space.distances(goal)[4 * 0 + east] == 4 * MOVE  # not old enough yet
    space.guide([2], [goal])
    assert space.distances(goal)[4 * 0 + east] == 4 * MOVE + 3 * CROWD_WEIGHT
    space.guide([], [goal])  # searched at the call before: kept for CROWD_AGE calls
    assert space.distances(goal)[4 * 0 + east] == 4 * MOVE + 3 * CROWD_WEIGHT


def test_crowd_guidance_needs_a_guidance() -> None:
    grid = Grid(np.ones((1, 5), dtype=bool))
    with pytest.raises(ValueError, match="needs a guidance"):
        StateSpace(grid, True, exact=True).guide([2], [4])


@settings(max_examples=40, deadline=None)
@given(grid_and_goal(), st.data())
def test_crowded_tables_equal_a_textbook_dijkstra(case: tuple[Grid, int], data: st.DataObject
                                                  ) -> None:
    """Forward costs of many values (the crowd's) take the bucket search: the same costs."""
    grid, goal = case
    cells = np.flatnonzero(grid.free.ravel()).tolist()
    robots = data.draw(st.lists(st.sampled_from(cells), unique=True))
    forward = crowded(grid, crisscross(grid, data.draw(st.integers(0, 5))), robots)
    assert guided_tables(grid, [goal], forward)[0].tolist() == dijkstra(grid, goal,
                                                                       forward.tolist())


def cell_dijkstra(grid: Grid, goal: int, forward: list[int]) -> list[int]:
    """Textbook Dijkstra from every cell to the goal (the oracle of :func:`guided_cell_tables`):
    a move from cell c heading d costs ``forward[4 * c + d]``, turns nothing; -1 if
    unreachable."""
    w, h = grid.width, grid.height
    free = grid.free.ravel()
    out = []
    for start in range(grid.size):
        if not free[start]:
            out.append(-1)
            continue
        best, heap, found = {start: 0}, [(0, start)], -1
        while heap:
            d, c = heapq.heappop(heap)
            if d > best[c]:
                continue
            if c == goal:
                found = d
                break
            x, y = c % w, c // w
            for hd, (dx, dy) in enumerate(STEP):
                nx, ny = x + dx, y + dy
                v = ny * w + nx
                if 0 <= nx < w and 0 <= ny < h and free[v] and d + forward[4 * c + hd] < \
                        best.get(v, 1 << 30):
                    best[v] = d + forward[4 * c + hd]
                    heapq.heappush(heap, (best[v], v))
        out.append(found)
    return out


@settings(max_examples=60, deadline=None)
@given(grid_and_goal(), st.data())
def test_cell_tables_equal_a_textbook_dijkstra(case: tuple[Grid, int], data: st.DataObject
                                               ) -> None:
    """Any forward costs of at least MOVE (drawn per state); without a penalty, MOVE times the
    moves of a breadth-first search."""
    grid, goal = case
    forward = np.array(data.draw(st.lists(st.integers(MOVE, 9), min_size=4 * grid.size,
                                          max_size=4 * grid.size)), dtype=np.int32)
    got = guided_cell_tables(grid, [goal], forward)[0].tolist()
    assert got == cell_dijkstra(grid, goal, forward.tolist())
    plain = guided_cell_tables(grid, [goal], corridor_lanes(grid, 0))[0]
    moves = cell_distance_rows(grid, [goal])[0]
    assert plain[grid.free.ravel()].tolist() == np.where(moves < 0, -1, MOVE * moves).tolist()


def test_corridor_lanes_alternate_by_hand() -> None:
    """Four shelf blocks between corridors: the corridor rows 0, 3, 6 run east, west, east
    (in order from the north), the corridor columns 0, 4, 8 south, north, south; a move
    against a lane costs the penalty more; an open map has no lanes."""
    free = np.ones((7, 9), dtype=bool)
    free[1:3, 1:4] = free[1:3, 5:8] = free[4:6, 1:4] = free[4:6, 5:8] = False
    grid = Grid(free)
    lanes = corridor_lanes(grid, 3).reshape(7, 9, 4)  # headings east, south, west, north
    assert [lanes[y, 2, 0] for y in (0, 3, 6)] == [2, 5, 2]  # east: along, against, along
    assert [lanes[y, 2, 2] for y in (0, 3, 6)] == [5, 2, 5]
    assert [lanes[1, x, 1] for x in (0, 4, 8)] == [2, 5, 2]  # south
    assert [lanes[1, x, 3] for x in (0, 4, 8)] == [5, 2, 5]
    assert lanes[0, 0].tolist() == [2, 2, 5, 5]  # a crossing: both lanes
    open_grid = Grid(np.ones((3, 3), dtype=bool))
    assert (corridor_lanes(open_grid, 3) == MOVE).all()  # no corridors, no lanes
    with pytest.raises(ValueError, match="at least 0"):
        corridor_lanes(grid, -1)
    with pytest.raises(ValueError, match="not a free cell"):
        guided_cell_tables(grid, [10], corridor_lanes(grid, 0))


@settings(max_examples=40, deadline=None)
@given(grid_and_goal(), st.integers(1, 4))
def test_the_best_option_costs_the_cell_table_entry(case: tuple[Grid, int], penalty: int
                                                    ) -> None:
    """With tables over the cells under a guidance: from every state off the goal that can
    reach it, the cheapest move facing its cell costs the cell's table entry (Bellman), a
    wait one MOVE more, and a move that needs turns a MOVE more per turn."""
    grid, goal = case
    forward = corridor_lanes(grid, penalty)
    space = StateSpace(grid, True, exact=False, guidance=forward)
    table = space.distances(goal)
    index = space.index
    for s in range(space.n_states):
        opts = space.options[s]
        if not opts or table[index[s >> 2]] in (0, UNREACHABLE):
            continue
        costs = space.costs(table, opts)
        own = table[index[s >> 2]]
        assert costs[0] == own + MOVE
        assert min(cost - MOVE * turns for cost, (_, _, turns, _) in zip(costs, opts,
                                                                          strict=True)) == own
