"""Exact shortest-path distances on a grid: numpy breadth-first search by frontier expansion."""

from __future__ import annotations

import weakref

import numpy as np
import numpy.typing as npt

from gateway.planning.grid import Cell, Grid

_NEIGHBOUR_TABLES: weakref.WeakKeyDictionary[Grid, npt.NDArray[np.int64]] = (
    weakref.WeakKeyDictionary()
)


def neighbour_table(grid: Grid) -> npt.NDArray[np.int64]:
    """``(size + 1, 4)`` array of neighbour flat ids, padded with the sentinel ``size``.

    Row ``size`` (the sentinel) has only sentinel neighbours, so a gather never goes out of range.
    Cached per grid.
    """
    table = _NEIGHBOUR_TABLES.get(grid)
    if table is None:
        n = grid.size
        table = np.full((n + 1, 4), n, dtype=np.int64)
        for i in range(n):
            nbrs = grid.neighbour_ids(i)
            table[i, : len(nbrs)] = nbrs
        table.setflags(write=False)
        _NEIGHBOUR_TABLES[grid] = table
    return table


def distance_table(grid: Grid, goal: Cell) -> npt.NDArray[np.int32]:
    """Moves from every cell to ``goal`` (flat ids, int32); -1 where unreachable or blocked.

    Raises ``ValueError`` if ``goal`` is outside the map or an obstacle.
    """
    if not grid.is_free(goal):
        raise ValueError(f"goal {goal} is not a free cell of {grid!r}")
    n = grid.size
    table = neighbour_table(grid)
    dist = np.full(n + 1, -1, dtype=np.int32)
    frontier = np.array([grid.index(goal)], dtype=np.int64)
    dist[frontier] = 0
    dist[n] = 0  # the sentinel counts as visited so it is never expanded
    d = 0
    while frontier.size:
        d += 1
        cand = np.unique(table[frontier].ravel())
        cand = cand[dist[cand] < 0]
        dist[cand] = d
        frontier = cand
    return dist[:n].copy()
