"""The ADG: exact Type 2 edge sets on tiny plans, drop_waits, and agreement with brute force."""

from __future__ import annotations

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from gateway.execution.errors import ExecutionError
from gateway.execution.oneshot.adg import ADG
from gateway.planning.plan import Plan
from tests.execution.support import (
    brute_predecessors,
    brute_type2,
    is_one_robust,
    random_robust_plan,
)

# A crosses (1,1) left to right; B waits two steps above it, then crosses downwards.
CROSSING = [[(0, 1), (1, 1), (2, 1)], [(1, 0), (1, 0), (1, 0), (1, 1), (1, 2)]]
# Fig. 4 corridor: red drives first, blue (behind it) waits one step, then follows.
CORRIDOR = [[(1, 0), (2, 0), (3, 0), (4, 0), (5, 0)], [(0, 0), (0, 0), (1, 0), (2, 0), (3, 0)]]


def test_crossing_has_one_type2_edge() -> None:
    # A's a_1 leaves (1,1); B first enters (1,1) with a_2 (path_B[3] = (1,1)). B never enters
    # A's cells (0,1)/(2,1) and A never enters B's (1,0)/(1,2): nothing else.
    adg = ADG(Plan.of(CROSSING))
    assert list(adg.type2_edges()) == [(0, 1, 1, 2)]
    assert adg.n_vertices == 2 + 4
    assert set(adg.predecessors(adg.vertex(1, 2))) == {adg.vertex(1, 1), adg.vertex(0, 1)}


def test_corridor_edges_follow_the_leader() -> None:
    # red a_i leaves x=i+1, blue enters x=i+1 with a_{i+1}: r0->b1, r1->b2, r2->b3;
    # red never enters a cell blue leaves later (blue leaves 0,1,2 after red left them).
    assert list(ADG(Plan.of(CORRIDOR)).type2_edges()) == [(0, 0, 1, 1), (0, 1, 1, 2),
                                                          (0, 2, 1, 3)]


def test_only_the_first_later_entry_per_robot() -> None:
    # X = (1,0). A leaves X with a_0. B enters X with a_1, leaves with a_2, re-enters with a_3,
    # leaves with a_4. C enters X with a_6, and enters (0,0) (which B left with a_1) with a_5.
    # By the definition (per leaving action and other robot, the FIRST later entry):
    #   A a_0 -> B a_1 (not B a_3), A a_0 -> C a_6; B a_1 -> C a_5; B a_2 -> C a_6;
    #   B a_4 -> C a_6. Nobody else re-enters a cell someone left.
    a = [(1, 0), (2, 0)]
    b = [(0, 0), (0, 0), (1, 0), (1, 1), (1, 0), (1, 1), (1, 2)]
    c = [(0, 3), (0, 3), (0, 3), (0, 3), (0, 2), (0, 1), (0, 0), (1, 0)]
    assert is_one_robust([a, b, c])
    edges = list(ADG(Plan.of([a, b, c])).type2_edges())
    assert edges == [(0, 0, 1, 1), (0, 0, 2, 6), (1, 1, 2, 5), (1, 2, 2, 6), (1, 4, 2, 6)]


def test_drop_waits_removes_wait_vertices_only() -> None:
    adg = ADG(Plan.of(CROSSING), drop_waits=True)
    assert adg.n_vertices == 2 + 2
    assert list(adg.type2_edges()) == [(0, 1, 1, 2)]
    assert adg.t1_pred(adg.vertex(1, 2)) == -1  # B's first kept action
    with pytest.raises(ExecutionError, match="is a wait"):
        adg.vertex(1, 0)


def test_bad_plans_and_lookups_are_rejected() -> None:
    with pytest.raises(ExecutionError, match="jumps from"):
        ADG(Plan.of([[(0, 0), (2, 0)]]))
    adg = ADG(Plan.of(CORRIDOR))
    with pytest.raises(ExecutionError, match="unknown robot 2"):
        adg.vertex(2, 0)
    with pytest.raises(ExecutionError, match="no action 4"):
        adg.vertex(0, 4)


@settings(max_examples=100, deadline=None)
@given(seed=st.integers(0, 10**6), robots=st.integers(1, 6), horizon=st.integers(1, 14),
       drop_waits=st.booleans())
def test_edges_match_the_all_pairs_definition(seed: int, robots: int, horizon: int,
                                              drop_waits: bool) -> None:
    paths = random_robust_plan(seed, 5, 4, robots, horizon)
    plan = Plan.of(paths)
    adg = ADG(plan, drop_waits=drop_waits)
    assert sorted(adg.type2_edges()) == brute_type2(plan.paths)
    expected = brute_predecessors(plan.paths, drop_waits)
    got = {(adg.robot_of[v], adg.step_of[v]): {(adg.robot_of[p], adg.step_of[p])
                                               for p in adg.predecessors(v)}
           for v in range(adg.n_vertices)}
    assert got == expected
    # the topological order respects every edge
    assert all(adg.topo[p] < adg.topo[v] for v in range(adg.n_vertices)
               for p in adg.predecessors(v))


@given(seed=st.integers(0, 10**6), robots=st.integers(1, 6), horizon=st.integers(1, 14),
       pick=st.integers(0, 2**20))
@settings(max_examples=60, deadline=None)
def test_gated_waits_drop_only_those_waits_and_keep_every_ordering(
        seed: int, robots: int, horizon: int, pick: int) -> None:
    plan = Plan.of(random_robust_plan(seed, 5, 5, robots, horizon))
    full = ADG(plan)
    waits = sorted((full.robot_of[v], full.step_of[v]) for v in range(full.n_vertices)
                   if full.kind[v] == "wait")
    gated = frozenset(w for i, w in enumerate(waits) if pick >> (i % 20) & 1)
    adg = ADG(plan, gated=gated)
    assert adg.n_vertices == full.n_vertices - len(gated)
    assert set(adg.type2_edges()) == set(full.type2_edges())
    for r, i in gated:
        with pytest.raises(ExecutionError, match="is a wait"):
            adg.vertex(r, i)
    kept = {(adg.robot_of[v], adg.step_of[v]) for v in range(adg.n_vertices)}
    assert kept == {(full.robot_of[v], full.step_of[v]) for v in range(full.n_vertices)} - gated
