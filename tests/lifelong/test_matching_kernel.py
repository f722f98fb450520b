"""The compiled greedy matching over groups of tasks (one distance column per group) gives
the pairs of the plain greedy matching over all pairs, in the same order (the oracle below
sorts every (cost, robot, task)), ties and unreachable tasks included, whether a group keeps one
nearest robot (its list is built again often) or more than there are."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from gateway.execution.lifelong.matching_kernel import greedy_groups

UNREACHABLE = 1000


def all_pairs_greedy(dist: np.ndarray, column: np.ndarray, extra: np.ndarray
                     ) -> list[tuple[int, int]]:
    """Every (cost, robot, task) sorted, each robot and task taken once, in order."""
    out: list[tuple[int, int]] = []
    rows: set[int] = set()
    used: set[int] = set()
    pairs = []
    for r in range(dist.shape[0]):
        for t in range(column.size):
            d = int(dist[r, column[t]])
            pairs.append(((d if d >= 0 else UNREACHABLE) + int(extra[t]), r, t))
    for _, r, t in sorted(pairs):
        if r not in rows and t not in used:
            out.append((r, t))
            rows.add(r)
            used.add(t)
    return out


@pytest.mark.parametrize("nearest", [1, 2, 32])
@settings(max_examples=150, deadline=None)
@given(data=st.data(), robots=st.integers(0, 9), groups=st.integers(1, 7),
       tasks=st.integers(0, 12))
def test_groups_give_the_all_pairs_matching(nearest: int, data: st.DataObject, robots: int,
                                            groups: int, tasks: int) -> None:
    values = st.integers(-1, 5)  # few values: many ties; -1 is unreachable
    dist = np.array(data.draw(st.lists(st.lists(values, min_size=groups, max_size=groups),
                                       min_size=robots, max_size=robots)),
                    dtype=np.int32).reshape(robots, groups)
    column = np.array(data.draw(st.lists(st.integers(0, groups - 1), min_size=tasks,
                                         max_size=tasks)), dtype=np.int64)
    extra = np.array(data.draw(st.lists(st.integers(-3, 3), min_size=tasks, max_size=tasks)),
                     dtype=np.int64)
    got_r, got_t = greedy_groups(dist.T, column, extra, UNREACHABLE, nearest)
    assert list(zip(got_r.tolist(), got_t.tolist(), strict=True)) == all_pairs_greedy(
        dist, column, extra)


def test_a_robot_taken_first_sends_its_group_to_the_next_robot() -> None:
    # robot 0 and 1 both want group 0 (distance 1 and 2); group 0 has tasks 0 (extra 0) and 2
    # (extra 5), group 1 task 1 (extra 0) at distance 4 and 3; one nearest robot a group
    dist = np.array([[1, 4], [2, 3]], dtype=np.int32)
    column = np.array([0, 1, 0], dtype=np.int64)
    extra = np.array([0, 0, 5], dtype=np.int64)
    robots, tasks = greedy_groups(dist.T, column, extra, UNREACHABLE, 1)
    # (1, r0, t0) first; r1 then weighs t2 at 2 + 5 against t1 at 3: t1
    assert list(zip(robots.tolist(), tasks.tolist(), strict=True)) == [(0, 0), (1, 1)]
