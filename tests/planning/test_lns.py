"""LNS over a planned window (:mod:`gateway.planning.lns`): hand-derived paths and costs, and
properties against the planner's rules (the window stays valid, its cost never rises)."""

from __future__ import annotations

import random

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from gateway.planning.grid import Grid
from gateway.planning.guidance import MOVE, crisscross
from gateway.planning.lns import REACH, best_path, path_cost, refine, window_cost
from gateway.planning.pibt import StateSpace, WindowedPIBT
from tests.lifelong.support import small_problem

ROW = Grid(np.ones((1, 6), dtype=bool))  # cells 0..5 in a row
EAST = 0


def _space(grid: Grid) -> StateSpace:
    """Exact tables guided by lanes without a penalty: every action costs MOVE."""
    return StateSpace(grid, True, exact=True, guidance=crisscross(grid, 0))


def _free(steps: int, size: int = 6) -> list[list[int]]:
    return [[-1] * size for _ in range(steps + 1)]


def test_a_free_robot_drives_to_its_goal_and_stays() -> None:
    space = _space(ROW)
    path = best_path(space, space.state(0, EAST), [2], _free(3), 0, set())
    assert path == [space.state(c, EAST) for c in (0, 1, 2, 2)]
    # two moves of MOVE, then the goal is reached (the wait after it is free)
    assert path_cost(space, path, [2]) == 2 * MOVE - REACH


def test_a_held_robot_waits_first() -> None:
    space = _space(ROW)
    path = best_path(space, space.state(0, EAST), [2], _free(3), 1, set())
    assert path == [space.state(c, EAST) for c in (0, 0, 1, 2)]
    assert path_cost(space, path, [2]) == 3 * MOVE - REACH


def test_a_blocked_robot_waits_rather_than_turns_away() -> None:
    space = _space(ROW)
    occ = _free(3)
    for row in occ:
        row[1] = 7  # another robot stands on cell 1 throughout
    path = best_path(space, space.state(0, EAST), [2], occ, 0, set())
    assert path == [space.state(0, EAST)] * 4
    assert path_cost(space, path, [2]) == 3 * MOVE + 2 * MOVE  # three waits, two moves left


def test_no_robot_enters_a_cell_held_the_timestep_before() -> None:
    """Robot 7 drives east from cell 1 ahead: the robot behind may enter cell 1 only at the
    timestep after 7 left it (1-robust), so it trails one cell further back than following
    would; cells of ``avoid`` are not entered at all."""
    space = _space(ROW)
    occ = _free(3)
    for t, c in enumerate((1, 2, 3, 4)):
        occ[t][c] = 7
    path = best_path(space, space.state(0, EAST), [5], occ, 0, set())
    assert [space.cell_of[s] for s in path] == [0, 0, 1, 2]
    assert best_path(space, space.state(0, EAST), [5], _free(3), 0, {1}) == (
        [space.state(0, EAST)] * 4)


def test_a_robot_on_its_cell_at_the_next_timestep_leaves_no_path() -> None:
    space = _space(ROW)
    occ = _free(2)
    occ[1][0] = 7  # someone is planned onto the robot's own cell
    assert best_path(space, space.state(0, EAST), [5], occ, 0, set()) is None


def _valid(space: StateSpace, states: list[list[int]], hold: list[int]) -> None:
    """The planner's rules, checked directly: actions are successors, distinct cells at each
    timestep, nobody enters a cell held the timestep before, holds wait."""
    cell_of = space.cell_of
    for t in range(1, len(states)):
        before, now = states[t - 1], states[t]
        cells = [cell_of[s] for s in now]
        assert len(set(cells)) == len(cells)
        held = {cell_of[s]: r for r, s in enumerate(before)}
        for r, (s, s2) in enumerate(zip(before, now, strict=True)):
            assert s2 in [m[0] for m in space.moves(s)]
            if t <= hold[r]:
                assert s2 == s
            if cell_of[s2] != cell_of[s]:
                assert held.get(cell_of[s2], r) == r


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 10_000), robots=st.integers(2, 30), steps=st.integers(1, 5),
       lanes=st.sampled_from([0, 3]), turn=st.sampled_from([MOVE, 6]),
       rounds=st.integers(1, 60), by_priority=st.booleans())
def test_refining_keeps_the_rules_and_never_costs_more(seed: int, robots: int, steps: int,
                                                        lanes: int, turn: int, rounds: int,
                                                        by_priority: bool) -> None:
    """A PIBT window of random robots and goals on a random map, refined (groups in a random
    order or by priority): every rule holds, and the window's cost falls by exactly what
    :func:`refine` reports (0 or more)."""
    problem = small_problem(seed, robots=robots, size=10)
    grid = problem.grid
    space = StateSpace(grid, True, exact=True, guidance=crisscross(grid, lanes), turn=turn)
    rng = random.Random(seed)
    goals = [list(problem.tasks[r]) if rng.random() < 0.9 else [] for r in range(robots)]
    hold = [rng.choice([0, 0, 1, 2]) for _ in range(robots)]
    states = [space.state(c, rng.randrange(4)) for c in problem.starts]
    win = WindowedPIBT(space, robots, seed=seed).plan(states, goals, steps, hold)
    window = [list(row) for row in win.states]
    before = window_cost(space, window, goals)
    priority = [rng.randrange(10) for _ in range(robots)] if by_priority else None
    gained = refine(space, grid.width, window, goals, hold, (), rounds, random.Random(seed),
                    priority)
    assert gained >= 0
    assert window_cost(space, window, goals) == before - gained
    assert window[0] == win.states[0]
    _valid(space, window, hold)


def test_refining_is_a_function_of_its_inputs() -> None:
    problem = small_problem(5, robots=30, size=10)
    grid = problem.grid
    space = _space(grid)
    goals = [list(t) for t in problem.tasks[:30]]
    states = [space.state(c, EAST) for c in problem.starts]
    outs = []
    for _ in range(2):
        win = WindowedPIBT(space, 30, seed=1, lns=40).plan(states, goals, 4)
        outs.append((win.states, win.reached))
    assert outs[0] == outs[1]


def test_refining_finds_cheaper_windows_in_a_crowd() -> None:
    """25 robots on a 10 x 10 map (seeded): PIBT's window leaves something to improve."""
    problem = small_problem(0, robots=25, size=10)
    grid = problem.grid
    space = StateSpace(grid, True, exact=True, guidance=crisscross(grid, 3), turn=6)
    goals = [list(t) for t in problem.tasks[:25]]
    states = [space.state(c, EAST) for c in problem.starts]
    window = [list(row) for row in WindowedPIBT(space, 25, seed=0).plan(states, goals, 4).states]
    before = window_cost(space, window, goals)
    assert refine(space, grid.width, window, goals, None, (), 50, random.Random(0)) > 0
    assert window_cost(space, window, goals) < before
