"""The schedulers' greedy matching over per-robot shortlists gives the pairs of the plain
greedy matching over all pairs (the oracle below sorts every pair), ties included, also when
shortlists of one task must widen again and again."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from gateway.execution.lifelong import tasks
from gateway.execution.lifelong.tasks import _greedy_pairs


def all_pairs_greedy(cost: np.ndarray) -> dict[int, int]:
    """Every (cost, row, column) sorted, each row and column taken once (row r = robot r)."""
    out: dict[int, int] = {}
    used: set[int] = set()
    for _, r, t in sorted((int(cost[r, t]), r, t) for r in range(cost.shape[0])
                          for t in range(cost.shape[1])):
        if r not in out and t not in used:
            out[r] = t
            used.add(t)
    return out


@pytest.mark.parametrize("shortlist", [1, 2, 32])
@settings(max_examples=60, deadline=None)
@given(cost=arrays(np.int64, st.tuples(st.integers(1, 12), st.integers(1, 12)),
                   elements=st.integers(0, 6)))  # few values: many ties
def test_shortlists_give_the_all_pairs_matching(shortlist: int, cost: np.ndarray) -> None:
    free = [(r, 0) for r in range(cost.shape[0])]
    ids = np.arange(cost.shape[1], dtype=np.int64)
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(tasks, "SHORTLIST", shortlist)
        mp.setattr(tasks, "_ROWS", 3)
        got = _greedy_pairs(lambda rows: cost[rows], free, ids)
    assert got == all_pairs_greedy(cost)
