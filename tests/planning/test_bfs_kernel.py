"""The compiled breadth-first search equals a textbook BFS on random graphs (several source
groups, repeated sources, isolated nodes, the sentinel padding)."""

from __future__ import annotations

from collections import deque

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from gateway.planning.bfs_kernel import bfs_groups


def textbook(adj: list[list[int]], sources: list[int]) -> list[int]:
    """Distances from the nearest of ``sources`` along ``adj`` (-1: not reached)."""
    dist = [-1] * len(adj)
    queue: deque[int] = deque()
    for s in sources:
        if dist[s] < 0:
            dist[s] = 0
            queue.append(s)
    while queue:
        u = queue.popleft()
        for v in adj[u]:
            if dist[v] < 0:
                dist[v] = dist[u] + 1
                queue.append(v)
    return dist


@st.composite
def graphs(draw: st.DrawFn) -> tuple[list[list[int]], list[list[int]]]:
    """A directed graph of 1-40 nodes, out-degree <= 4, and 1-6 groups of 1-4 sources."""
    n = draw(st.integers(1, 40))
    adj = [draw(st.lists(st.integers(0, n - 1), max_size=4)) for _ in range(n)]
    groups = draw(st.lists(st.lists(st.integers(0, n - 1), min_size=1, max_size=4),
                           min_size=1, max_size=6))
    return adj, groups


@settings(max_examples=200, deadline=None)
@given(graphs())
def test_compiled_search_equals_textbook_bfs(case: tuple[list[list[int]], list[list[int]]]
                                             ) -> None:
    adj, groups = case
    n = len(adj)
    table = np.full((n + 1, 4), n, dtype=np.int32)
    for i, row in enumerate(adj):
        table[i, : len(row)] = row
    flat = np.array([s for g in groups for s in g], dtype=np.int64)
    bounds = np.array([0, *np.cumsum([len(g) for g in groups])], dtype=np.int64)
    out = np.full((len(groups), n), -1, dtype=np.int32)
    bfs_groups(table, flat, bounds, out)
    for k, g in enumerate(groups):
        assert out[k].tolist() == textbook(adj, g)
