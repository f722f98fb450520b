"""The plan validator on hand-made plans: valid ones and one of each kind of violation."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from gateway.planning.grid import Cell, Grid
from gateway.planning.plan import Plan
from gateway.planning.validate import InvalidPlan, check_plan, plan_violations


def grid_of(*rows: str) -> Grid:
    """A grid from rows of '.' (free) and '@' (blocked)."""
    return Grid(np.array([[c == "." for c in row] for row in rows]))


OPEN3 = grid_of("...", "...", "...")


def test_valid_plan_has_no_violations() -> None:
    # Agent 1 waits one step so that agent 0 has left (1,1) a full step before it enters.
    starts, goals = [(0, 1), (1, 0)], [(2, 1), (1, 2)]
    paths = [[(0, 1), (1, 1), (2, 1)], [(1, 0), (1, 0), (1, 0), (1, 1), (1, 2)]]
    assert plan_violations(OPEN3, starts, goals, paths) == []
    check_plan(OPEN3, starts, goals, Plan.of(paths))


def test_vertex_conflict() -> None:
    paths = [[(0, 1), (1, 1), (2, 1)], [(1, 0), (1, 1), (1, 2)]]
    assert plan_violations(OPEN3, [(0, 1), (1, 0)], [(2, 1), (1, 2)], paths) == [
        "vertex conflict: agents 0 and 1 at (1, 1) at t=1"]


def test_swap_conflict() -> None:
    paths = [[(0, 0), (1, 0)], [(1, 0), (0, 0)]]
    assert plan_violations(OPEN3, [(0, 0), (1, 0)], [(1, 0), (0, 0)], paths) == [
        "swap conflict (not 1-robust): agent 0 is at (1, 0) at t=1, where agent 1 was at t=0",
        "swap conflict (not 1-robust): agent 1 is at (0, 0) at t=1, where agent 0 was at t=0",
    ]


def test_following_conflict() -> None:
    corridor = grid_of("....")
    paths = [[(0, 0), (1, 0), (2, 0)], [(1, 0), (2, 0), (3, 0)]]
    assert plan_violations(corridor, [(0, 0), (1, 0)], [(2, 0), (3, 0)], paths) == [
        "following conflict (not 1-robust): agent 0 is at (1, 0) at t=1, where agent 1 was at t=0",
        "following conflict (not 1-robust): agent 0 is at (2, 0) at t=2, where agent 1 was at t=1",
    ]


def test_cycle_conflict_is_a_following_conflict_for_every_agent() -> None:
    square = grid_of("..", "..")
    cycle: list[Cell] = [(0, 0), (1, 0), (1, 1), (0, 1)]
    starts = cycle
    goals = cycle[1:] + cycle[:1]
    paths = [[s, g] for s, g in zip(starts, goals, strict=True)]
    found = plan_violations(square, starts, goals, paths)
    assert len(found) == 4
    assert all(v.startswith("following conflict") for v in found)
    assert not any("vertex" in v for v in found)


def test_agent_stays_on_its_goal_after_its_path_ends() -> None:
    # Agent 0 is done at t=1 and stays on (1,0); agent 1 walks over it at t=3.
    strip = grid_of("...", "...")
    paths = [[(0, 0), (1, 0)], [(2, 0), (2, 0), (2, 0), (1, 0), (1, 1)]]
    assert plan_violations(strip, [(0, 0), (2, 0)], [(1, 0), (1, 1)], paths) == [
        "vertex conflict: agents 0 and 1 at (1, 0) at t=3"]


def test_entering_a_goal_the_step_after_its_agent_arrived_there_is_not_1_robust() -> None:
    strip = grid_of("...")
    paths = [[(1, 0), (2, 0)], [(0, 0), (1, 0)]]
    assert plan_violations(strip, [(1, 0), (0, 0)], [(2, 0), (1, 0)], paths) == [
        "following conflict (not 1-robust): agent 1 is at (1, 0) at t=1, where agent 0 was at t=0"]


@pytest.mark.parametrize(("path", "message"), [
    ([(0, 0), (2, 0)], "agent 0 t=1: (0, 0) -> (2, 0) is neither a wait nor a move to a "
                       "4-neighbour"),
    ([(0, 0), (1, 1), (2, 0)], "agent 0 t=1: (0, 0) -> (1, 1) is neither a wait nor a move to "
                               "a 4-neighbour"),
    ([(0, 0), (0, 1), (1, 1), (2, 1), (2, 0)], "agent 0 t=2: (1, 1) is not a free cell"),
    ([(0, 0), (-1, 0), (0, 0), (1, 0), (2, 0)], "agent 0 t=1: (-1, 0) is not a free cell"),
    ([(1, 0), (2, 0)], "agent 0: path starts at (1, 0), its start is (0, 0)"),
    ([(0, 0), (1, 0)], "agent 0: path ends at (1, 0), its goal is (2, 0)"),
    ([], "agent 0: empty path"),
])
def test_bad_single_paths(path: list[Cell], message: str) -> None:
    g = grid_of("...", ".@.")
    found = plan_violations(g, [(0, 0)], [(2, 0)], [path])
    assert message in found
    with pytest.raises(InvalidPlan) as err:
        check_plan(g, [(0, 0)], [(2, 0)], [path])
    assert message in err.value.violations


def test_wrong_number_of_paths() -> None:
    assert plan_violations(OPEN3, [(0, 0), (1, 1)], [(0, 1), (2, 2)], [[(0, 0), (0, 1)]]) == [
        "the plan has 1 paths for 2 agents"]


def _brute_force_valid(grid: Grid, starts: list[Cell], goals: list[Cell],
                       paths: list[list[Cell]]) -> bool:
    """The definition read literally, over all pairs of agents and all timesteps."""
    def pos(k: int, t: int) -> Cell:
        return paths[k][min(t, len(paths[k]) - 1)]

    horizon = max(len(p) for p in paths) + 1
    for k, p in enumerate(paths):
        if p[0] != starts[k] or p[-1] != goals[k] or not all(grid.is_free(c) for c in p):
            return False
        if any(abs(a[0] - b[0]) + abs(a[1] - b[1]) > 1 for a, b in itertools.pairwise(p)):
            return False
    for j, k in itertools.permutations(range(len(paths)), 2):
        for t in range(horizon):
            if pos(j, t) == pos(k, t) or (t >= 1 and pos(k, t) == pos(j, t - 1)):
                return False
    return True


@st.composite
def _random_plans(draw: st.DrawFn) -> tuple[list[Cell], list[Cell], list[list[Cell]]]:
    """Mostly random walks (waits and unit moves), so that many plans are nearly valid."""
    n = draw(st.integers(1, 3))
    cells = st.tuples(st.integers(0, 2), st.integers(0, 2))
    steps = st.sampled_from([(0, 0), (1, 0), (-1, 0), (0, 1), (0, -1), (2, 0)])
    paths = []
    for _ in range(n):
        path = [draw(cells)]
        for dx, dy in draw(st.lists(steps, max_size=5)):
            path.append((path[-1][0] + dx, path[-1][1] + dy))
        paths.append(path)
    starts = [p[0] for p in paths]
    goals = [p[-1] if draw(st.booleans()) else draw(cells) for p in paths]
    return starts, goals, paths


@settings(max_examples=300, deadline=None)
@given(_random_plans())
def test_validator_agrees_with_the_definition_read_literally(
        case: tuple[list[Cell], list[Cell], list[list[Cell]]]) -> None:
    starts, goals, paths = case
    g = grid_of("...", ".@.", "...")
    assert (plan_violations(g, starts, goals, paths) == []) == _brute_force_valid(
        g, starts, goals, paths)
