"""CBS: valid plans whose SOC equals the exhaustive joint-state optimum, and its edge cases."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st

from gateway.planning import cbs as cbs_module
from gateway.planning.cbs import CBSOptions, solve_cbs
from gateway.planning.grid import Cell, Grid
from gateway.planning.plan import NeverExpires, NoSolution
from gateway.planning.solver import solve
from tests.planning.exhaustive import optimal_soc
from tests.planning.support_planning import (
    CountingDeadline,
    Forbidden,
    assert_valid,
    grid_of,
    small_instances,
)

PLAIN = CBSOptions(
    cardinal=False, heuristic=False, dependency=False, bypass=False, target=False,
    avoidance=False, rectangle=False,
)
SHORT_BUDGET = 3000
"""Deadline checks CBS gets first: enough for nearly every generated instance."""
LONG_BUDGET = 300_000
"""Deadline checks for a solvable instance that exhausted :data:`SHORT_BUDGET`."""
SETTINGS = settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.too_slow])


def check_against_oracle(
    grid: Grid,
    starts: list[Cell],
    goals: list[Cell],
    forbidden: list[Forbidden],
    options: CBSOptions = CBSOptions(),  # noqa: B008 - frozen
    timeout_is_inconclusive: bool = False,
) -> None:
    """CBS agrees with the exhaustive optimum. Its budget counts deadline checks (no clock).

    A timeout is not a proof of "no solution". On an unsolvable instance it is expected (CBS
    rarely proves infeasibility). On a solvable one CBS gets :data:`LONG_BUDGET` and must then
    answer (:func:`test_an_instance_past_the_first_budget_is_solved` needs it), or,
    with ``timeout_is_inconclusive`` (plain CBS, which can exhaust any budget on a 3-agent 4x4
    instance), the example is discarded.
    """
    best = optimal_soc(grid, starts, goals, forbidden, max_cost=80)
    for budget in (SHORT_BUDGET, LONG_BUDGET):
        try:
            sol = solve_cbs(grid, starts, goals, deadline=CountingDeadline(budget),
                            forbidden=forbidden, options=options)
            break
        except NoSolution as exc:
            if not exc.timed_out or best is None:
                assert best is None
                return
            if timeout_is_inconclusive:
                assume(False)
    else:
        raise AssertionError(f"CBS ran out of its budget (optimum SOC {best})")
    assert_valid(grid, starts, goals, sol.plan, forbidden)
    assert sol.optimal
    assert sol.plan.soc == best


@SETTINGS
@given(small_instances(5, 4, (2, 3)))
def test_cbs_soc_equals_exhaustive_optimum(
    inst: tuple[Grid, list[Cell], list[Cell], list[Forbidden]],
) -> None:
    check_against_oracle(*inst)


def test_an_instance_past_the_first_budget_is_solved() -> None:
    """Three robots in a 4x3 room with two blocked cells (optimum SOC 25, found by a random
    search for the cheapest such instance): full CBS exhausts :data:`SHORT_BUDGET` here and
    must still answer optimally within :data:`LONG_BUDGET`."""
    grid = grid_of("....", ".@..", "..@.")
    starts, goals = [(2, 1), (0, 1), (3, 0)], [(2, 1), (0, 0), (1, 2)]
    with pytest.raises(NoSolution):  # else this no longer tests the second budget
        solve_cbs(grid, starts, goals, deadline=CountingDeadline(SHORT_BUDGET))
    check_against_oracle(grid, starts, goals, [])


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(small_instances(7, 6, (2, 2)))
def test_two_agents_on_larger_maps_match_the_optimum(
    inst: tuple[Grid, list[Cell], list[Cell], list[Forbidden]],
) -> None:
    # Larger open areas are where the rectangle and target reasoning fire.
    check_against_oracle(*inst)


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(small_instances(4, 4, (2, 3)))
def test_plain_cbs_matches_the_optimum_too(
    inst: tuple[Grid, list[Cell], list[Cell], list[Forbidden]],
) -> None:
    check_against_oracle(*inst, options=PLAIN, timeout_is_inconclusive=True)


@st.composite
def same_way_pairs(draw: st.DrawFn) -> tuple[Grid, list[Cell], list[Cell], list[Forbidden]]:
    """Two agents starting near one corner and heading for the opposite one (mirrored at
    random), on a nearly open grid: the shape of rectangle conflicts."""
    w, h = draw(st.integers(4, 7)), draw(st.integers(4, 7))
    cells = [(x, y) for y in range(h) for x in range(w)]
    blocked = draw(st.sets(st.sampled_from(cells), max_size=3))
    corner = st.tuples(st.integers(0, 2), st.integers(0, 2))
    starts = draw(st.lists(corner, min_size=2, max_size=2, unique=True))
    goals = [(w - 1 - x, h - 1 - y) for x, y in
             draw(st.lists(corner, min_size=2, max_size=2, unique=True))]
    if draw(st.booleans()):
        starts, goals = [(w - 1 - x, y) for x, y in starts], [(w - 1 - x, y) for x, y in goals]
    if draw(st.booleans()):
        starts, goals = [(x, h - 1 - y) for x, y in starts], [(x, h - 1 - y) for x, y in goals]
    blocked -= set(starts) | set(goals)
    grid = Grid(np.array([[(x, y) not in blocked for x in range(w)] for y in range(h)]))
    return grid, starts, goals, []


@settings(max_examples=80, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(same_way_pairs())
def test_same_way_pairs_match_the_optimum(
    inst: tuple[Grid, list[Cell], list[Cell], list[Forbidden]],
) -> None:
    check_against_oracle(*inst)


def test_rectangle_crossing_is_solved_optimally() -> None:
    # Both agents move right/down with start offsets one step apart, so every pair of
    # shortest paths meets 0 or 1 steps apart: a 1-robust rectangle.
    grid = grid_of("......", "......", "......", "......", "......", "......")
    starts, goals = [(0, 1), (1, 0)], [(5, 4), (4, 5)]
    for options in (CBSOptions(), CBSOptions(rectangle=False)):
        check_against_oracle(grid, starts, goals, [], options)
    sol = solve_cbs(grid, starts, goals, deadline=NeverExpires())
    assert sol.expanded_nodes <= 3  # the rectangle split is cardinal on both sides


def test_agent_on_its_goal_steps_aside() -> None:
    # Hand-solved in test_exhaustive: B crosses A's goal; SOC 7 (B 3, A 4).
    grid = grid_of("...", "@.@")
    sol = solve_cbs(grid, [(1, 0), (0, 0)], [(1, 0), (2, 0)], deadline=NeverExpires())
    assert_valid(grid, [(1, 0), (0, 0)], [(1, 0), (2, 0)], sol.plan)
    assert sol.plan.soc == 7


def test_mid_run_configuration_with_robots_packed_and_on_goals() -> None:
    # Robots left mid-run: adjacent to each other, two already on their goals.
    grid = grid_of(".....", "..@..", ".....")
    starts = [(0, 0), (1, 0), (2, 0), (3, 2), (4, 2)]
    goals = [(4, 0), (1, 0), (0, 2), (3, 2), (2, 2)]
    sol = solve_cbs(grid, starts, goals, deadline=NeverExpires())
    assert_valid(grid, starts, goals, sol.plan)
    lower = sum(abs(s[0] - g[0]) + abs(s[1] - g[1]) for s, g in zip(starts, goals, strict=True))
    assert sol.plan.soc >= lower


def test_forbidden_window_is_respected_and_priced() -> None:
    # One agent along a 5-cell corridor; the middle cell is closed during t=1..3, so it cannot
    # pass before t=4 and arrives at t=6 instead of 4.
    grid = grid_of(".....")
    forbidden = [((2, 0), 1, 3)]
    sol = solve_cbs(grid, [(0, 0)], [(4, 0)], deadline=NeverExpires(), forbidden=forbidden)
    assert_valid(grid, [(0, 0)], [(4, 0)], sol.plan, forbidden)
    assert sol.plan.soc == 6


def test_unreachable_goal_raises_no_solution() -> None:
    grid = grid_of("..@..")
    with pytest.raises(NoSolution) as err:
        solve_cbs(grid, [(0, 0)], [(4, 0)], deadline=NeverExpires())
    assert not err.value.timed_out


def test_forbidden_start_raises_no_solution() -> None:
    with pytest.raises(NoSolution):
        solve_cbs(grid_of("..."), [(0, 0)], [(2, 0)], deadline=NeverExpires(),
                  forbidden=[((0, 0), 0, 2)])


def test_deadline_expiry_raises_timed_out() -> None:
    # A swap in a corridor has no plan; CBS keeps branching until the deadline says stop.
    with pytest.raises(NoSolution) as err:
        solve_cbs(grid_of("...."), [(0, 0), (3, 0)], [(3, 0), (0, 0)],
                  deadline=CountingDeadline(50))
    assert err.value.timed_out


def test_solver_falls_back_to_prioritised_when_cbs_times_out() -> None:
    grid = grid_of("......", "......", "......")
    starts, goals = [(0, 0), (5, 0), (0, 2)], [(5, 2), (0, 2), (5, 0)]
    sol = solve(grid, starts, goals, deadline=CountingDeadline(0), fallback=NeverExpires())
    assert not sol.optimal
    assert_valid(grid, starts, goals, sol.plan)
    with pytest.raises(NoSolution) as err:
        solve(grid, starts, goals, deadline=CountingDeadline(0))
    assert err.value.timed_out
    assert solve(grid, starts, goals, deadline=NeverExpires()).optimal


@pytest.mark.parametrize(
    ("starts", "goals", "message"),
    [
        ([(0, 0)], [(2, 0), (1, 0)], "starts but"),
        ([(0, 0), (0, 0)], [(2, 0), (1, 0)], "share a start"),
        ([(0, 0), (1, 0)], [(2, 0), (2, 0)], "share a goal"),
        ([(0, 0)], [(5, 0)], "not a free cell"),
    ],
)
def test_malformed_instances_raise_value_error(
    starts: list[Cell], goals: list[Cell], message: str
) -> None:
    with pytest.raises(ValueError, match=message):
        solve_cbs(grid_of("..."), starts, goals, deadline=NeverExpires())


def test_sparse_avoidance_table_gives_the_same_optimum(monkeypatch: pytest.MonkeyPatch) -> None:
    # Large maps use a dict instead of a flat list for the conflict-avoidance counts.
    monkeypatch.setattr(cbs_module, "DENSE_AVOIDANCE", 0)
    grid = grid_of(".....", "..@..", ".....")
    starts = [(0, 0), (1, 0), (2, 0), (3, 2), (4, 2)]
    goals = [(4, 0), (1, 0), (0, 2), (3, 2), (2, 2)]
    check_against_oracle(grid, starts[:3], goals[:3], [])


@settings(max_examples=100, deadline=None)
@given(st.dictionaries(st.tuples(st.integers(0, 5), st.integers(0, 5)).filter(
    lambda e: e[0] < e[1]), st.integers(1, 3), max_size=10))
def test_weighted_vertex_cover_is_the_brute_force_minimum(
        weights: dict[tuple[int, int], int]) -> None:
    # the WDG heuristic's cover: least sum of integer x_v with x_a + x_b >= w on every edge
    def feasible(x: tuple[int, ...]) -> bool:
        return all(x[a] + x[b] >= w for (a, b), w in weights.items())

    best = min(sum(x) for x in itertools.product(range(4), repeat=6) if feasible(x))
    assert cbs_module.min_weighted_vertex_cover(weights) == best
    # with unit weights it is the plain vertex cover of the DG heuristic
    assert cbs_module.min_weighted_vertex_cover(dict.fromkeys(weights, 1)) == \
        cbs_module.min_vertex_cover(list(weights))


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(small_instances(5, 4, (2, 3)))
def test_weighted_dependency_heuristic_keeps_the_optimum_under_omni(
    inst: tuple[Grid, list[Cell], list[Cell], list[Forbidden]],
) -> None:
    # WDG is on by default under turning only (test_turning_cbs checks it there)
    check_against_oracle(*inst, options=CBSOptions(weighted=True))
