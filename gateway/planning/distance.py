"""Exact shortest-path distances on a grid: numpy breadth-first search by frontier expansion.

For the ``omni`` model over cells, for the ``turning`` model over ``(cell, heading)`` states
(searched backwards from the goal states).
"""

from __future__ import annotations

import weakref
from collections.abc import Sequence

import numpy as np
import numpy.typing as npt

from gateway.planning.grid import Cell, Grid
from gateway.planning.motion import HEADING_MOVES

_NEIGHBOUR_TABLES: weakref.WeakKeyDictionary[Grid, npt.NDArray[np.int64]] = (
    weakref.WeakKeyDictionary()
)
_PREDECESSOR_TABLES: weakref.WeakKeyDictionary[Grid, npt.NDArray[np.int64]] = (
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
    """``out[k]`` is :func:`distance_table` of ``goals[k]``, all searched in one pass."""
    for goal in goals:
        if not grid.is_free(goal):
            raise ValueError(f"goal {goal} is not a free cell of {grid!r}")
    if len(goals) > CHUNK:
        return np.concatenate(
            [distance_tables(grid, goals[i : i + CHUNK]) for i in range(0, len(goals), CHUNK)]
        )
    return _multi_bfs(neighbour_table(grid), [[grid.index(g)] for g in goals])


def _multi_bfs(table: npt.NDArray[np.int64],
               sources: Sequence[Sequence[int]]) -> npt.NDArray[np.int32]:
    """Breadth-first distances from each group of ``sources`` over the graph of ``table``.

    ``table`` is ``(n + 1, d)``: row i lists the nodes one step from node i (towards the
    sources), padded with the sentinel n, whose row holds only sentinels. ``out[k, i]`` is the
    number of steps from node i to the nearest node of ``sources[k]``; -1 if none is reachable.
    The searches run together on the disjoint union of one copy of the graph per group, so
    numpy's per-level overhead is paid once per level, not once per group and level.
    """
    n = table.shape[0] - 1
    block = n + 1  # each copy has its own sentinel at offset n
    k = len(sources)
    if not k:
        return np.zeros((0, n), dtype=np.int32)
    dist = np.full(k * block, -1, dtype=np.int32)
    offsets = np.arange(k, dtype=np.int64) * block
    dist[offsets + n] = 0  # sentinels count as visited so they are never expanded
    frontier = np.concatenate([np.asarray(src, dtype=np.int64) + offsets[i]
                               for i, src in enumerate(sources)])
    frontier = np.unique(frontier)
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


def turning_predecessor_table(grid: Grid) -> npt.NDArray[np.int64]:
    """``(4 * size + 1, 3)`` array: the ``turning`` states one timestep before each state.

    State ``4 * cell + heading``; its predecessors are the two turns into it and the state one
    cell behind it with the same heading (if that cell is free); padded with the sentinel
    ``4 * size``. Cached per grid.
    """
    table = _PREDECESSOR_TABLES.get(grid)
    if table is None:
        n = grid.size
        sentinel = 4 * n
        table = np.full((sentinel + 1, 3), sentinel, dtype=np.int64)
        free = grid.free.ravel()
        cells = np.nonzero(free)[0]
        xs, ys = cells % grid.width, cells // grid.width
        for h, (dx, dy) in enumerate(HEADING_MOVES):
            rows = 4 * cells + h
            table[rows, 0] = 4 * cells + (h + 1) % 4
            table[rows, 1] = 4 * cells + (h + 3) % 4
            bx, by = xs - dx, ys - dy
            inside = (bx >= 0) & (bx < grid.width) & (by >= 0) & (by < grid.height)
            behind = np.where(inside, by * grid.width + bx, 0)
            ok = inside & free[behind]
            table[rows[ok], 2] = 4 * behind[ok] + h
        table.setflags(write=False)
        _PREDECESSOR_TABLES[grid] = table
    return table


def turning_distance_tables(grid: Grid, goals: Sequence[Cell],
                            goal_headings: Sequence[int | None] | None = None,
                            ) -> npt.NDArray[np.int32]:
    """``out[k, 4 * cell + heading]``: timesteps of the ``turning`` model from that state to
    ``goals[k]`` (with heading ``goal_headings[k]``, any heading if None); -1 if unreachable.

    These are exact single-agent costs, hence admissible lower bounds for planning.
    Raises ``ValueError`` if a goal is outside the map or an obstacle.
    """
    for goal in goals:
        if not grid.is_free(goal):
            raise ValueError(f"goal {goal} is not a free cell of {grid!r}")
    fixed = list(goal_headings) if goal_headings is not None else [None] * len(goals)
    if len(fixed) != len(goals):
        raise ValueError(f"{len(goals)} goals but {len(fixed)} goal headings")
    chunk = CHUNK // 4  # four states per cell: the same memory per batch as omni
    if len(goals) > chunk:
        return np.concatenate([
            turning_distance_tables(grid, goals[i : i + chunk], fixed[i : i + chunk])
            for i in range(0, len(goals), chunk)])
    sources = [[4 * grid.index(g) + h] if h is not None
               else [4 * grid.index(g) + d for d in range(4)]
               for g, h in zip(goals, fixed, strict=True)]
    return _multi_bfs(turning_predecessor_table(grid), sources)
