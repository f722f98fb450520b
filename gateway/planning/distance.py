"""Exact shortest-path distances on a grid: numpy breadth-first search by frontier expansion."""

from __future__ import annotations

import weakref
from collections.abc import Sequence

import numpy as np
import numpy.typing as npt

from gateway.planning.grid import Cell, Grid

_NEIGHBOUR_TABLES: weakref.WeakKeyDictionary[Grid, npt.NDArray[np.int64]] = (
    weakref.WeakKeyDictionary()
)


CHUNK = 64
"""Goals searched together (larger batches lose more to cache misses than they save)."""


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
    return distance_tables(grid, [goal])[0]


def distance_tables(grid: Grid, goals: Sequence[Cell]) -> npt.NDArray[np.int32]:
    """``out[k]`` is :func:`distance_table` of ``goals[k]``, all searched in one pass.

    The breadth-first searches run together on the disjoint union of one copy of the grid per
    goal, so numpy's per-level overhead is paid once per level, not once per goal and level.
    """
    for goal in goals:
        if not grid.is_free(goal):
            raise ValueError(f"goal {goal} is not a free cell of {grid!r}")
    if len(goals) > CHUNK:
        return np.concatenate(
            [distance_tables(grid, goals[i : i + CHUNK]) for i in range(0, len(goals), CHUNK)]
        )
    n = grid.size
    block = n + 1  # each copy has its own sentinel cell at offset n
    table = neighbour_table(grid)
    k = len(goals)
    dist = np.full(k * block, -1, dtype=np.int32)
    offsets = np.arange(k, dtype=np.int64) * block
    dist[offsets + n] = 0  # sentinels count as visited so they are never expanded
    frontier = offsets + np.array([grid.index(g) for g in goals], dtype=np.int64)
    dist[frontier] = 0
    stamp = np.zeros(k * block, dtype=np.int64)  # dedupes a level without sorting it
    d = 0
    while frontier.size:
        d += 1
        base = frontier - frontier % block
        cand = (table[frontier - base] + base[:, None]).ravel()
        cand = cand[dist[cand] < 0]
        order = np.arange(cand.size)
        stamp[cand] = order
        cand = cand[stamp[cand] == order]
        dist[cand] = d
        frontier = cand
    return dist.reshape(k, block)[:, :n].copy()
