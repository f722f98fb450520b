"""Exact shortest-path distances on a grid: breadth-first search compiled with numba.

For the ``omni`` model over cells, for the ``turning`` model over ``(cell, heading)`` states
(searched backwards from the goal states). The search itself is
:func:`gateway.planning.bfs_kernel.bfs_groups`; this module builds the graphs it runs on
(vectorised, as int32 tables: 12 bytes a state under ``turning``) and checks the goals.
"""

from __future__ import annotations

import weakref
from collections.abc import Sequence

import numpy as np
import numpy.typing as npt

from gateway.planning.bfs_kernel import bfs_groups
from gateway.planning.grid import Cell, Grid
from gateway.planning.motion import HEADING_MOVES

_NEIGHBOUR_TABLES: weakref.WeakKeyDictionary[Grid, npt.NDArray[np.int32]] = (
    weakref.WeakKeyDictionary()
)
_PREDECESSOR_TABLES: weakref.WeakKeyDictionary[Grid, npt.NDArray[np.int32]] = (
    weakref.WeakKeyDictionary()
)
_FREE_INDEX: weakref.WeakKeyDictionary[Grid, npt.NDArray[np.int32]] = weakref.WeakKeyDictionary()
_COMPACT_TABLES: weakref.WeakKeyDictionary[Grid, npt.NDArray[np.int32]] = (
    weakref.WeakKeyDictionary()
)


def neighbour_table(grid: Grid) -> npt.NDArray[np.int32]:
    """``(size + 1, 4)`` array of neighbour flat ids, padded with the sentinel ``size``.

    Row ``size`` (the sentinel) has only sentinel neighbours, so a gather never goes out of range.
    Row i lists i's free neighbours in the order of :meth:`Grid.neighbour_ids`. Cached per grid.
    """
    table = _NEIGHBOUR_TABLES.get(grid)
    if table is None:
        n, w, h = grid.size, grid.width, grid.height
        free = grid.free.ravel()
        cells = np.arange(n, dtype=np.int64)
        xs, ys = cells % w, cells // w
        table = np.full((n + 1, 4), n, dtype=np.int32)
        fill = np.zeros(n, dtype=np.int64)
        for dx, dy in ((1, 0), (-1, 0), (0, 1), (0, -1)):  # Grid's MOVES order
            nx, ny = xs + dx, ys + dy
            inside = (nx >= 0) & (nx < w) & (ny >= 0) & (ny < h)
            nb = np.where(inside, ny * w + nx, 0)
            ok = free & inside & free[nb]
            table[cells[ok], fill[ok]] = nb[ok]
            fill += ok
        table.setflags(write=False)
        _NEIGHBOUR_TABLES[grid] = table
    return table


def distance_table(grid: Grid, goal: Cell) -> npt.NDArray[np.int32]:
    """Moves from every cell to ``goal`` (flat ids, int32); -1 where unreachable or blocked.

    Raises ``ValueError`` if ``goal`` is outside the map or an obstacle.
    """
    return distance_tables(grid, [goal])[0]


def distance_tables(grid: Grid, goals: Sequence[Cell]) -> npt.NDArray[np.int32]:
    """``out[k]`` is :func:`distance_table` of ``goals[k]``."""
    for goal in goals:
        if not grid.is_free(goal):
            raise ValueError(f"goal {goal} is not a free cell of {grid!r}")
    return _multi_bfs(neighbour_table(grid), [[grid.index(g)] for g in goals])


def _multi_bfs(table: npt.NDArray[np.int32],
               sources: Sequence[Sequence[int]]) -> npt.NDArray[np.int32]:
    """Breadth-first distances from each group of ``sources`` over the graph of ``table``.

    ``table`` is ``(n + 1, d)``: row i lists the nodes one step from node i (towards the
    sources), padded with the sentinel n. ``out[k, i]`` is the number of steps from node i to
    the nearest node of ``sources[k]``; -1 if none is reachable.
    """
    n = table.shape[0] - 1
    out = np.full((len(sources), n), -1, dtype=np.int32)
    if sources:
        flat = np.fromiter((s for group in sources for s in group), dtype=np.int64)
        bounds = np.zeros(len(sources) + 1, dtype=np.int64)
        np.cumsum([len(group) for group in sources], out=bounds[1:])
        bfs_groups(table, flat, bounds, out)
    return out


def turning_predecessor_table(grid: Grid) -> npt.NDArray[np.int32]:
    """``(4 * size + 1, 3)`` array: the ``turning`` states one timestep before each state.

    State ``4 * cell + heading``; its predecessors are the two turns into it and the state one
    cell behind it with the same heading (if that cell is free); padded with the sentinel
    ``4 * size``. Cached per grid.
    """
    table = _PREDECESSOR_TABLES.get(grid)
    if table is None:
        n = grid.size
        sentinel = 4 * n
        table = np.full((sentinel + 1, 3), sentinel, dtype=np.int32)
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
    sources = [[4 * grid.index(g) + h] if h is not None
               else [4 * grid.index(g) + d for d in range(4)]
               for g, h in zip(goals, fixed, strict=True)]
    return _multi_bfs(turning_predecessor_table(grid), sources)


def free_index(grid: Grid) -> npt.NDArray[np.int32]:
    """``(size,)``: each free cell's position among the free cells (row by row), -1 for an
    obstacle: the columns of a compact table (:func:`cell_distance_rows`). Cached per grid."""
    index = _FREE_INDEX.get(grid)
    if index is None:
        free = grid.free.ravel()
        index = np.full(free.size, -1, dtype=np.int32)
        index[free] = np.arange(int(free.sum()), dtype=np.int32)
        index.setflags(write=False)
        _FREE_INDEX[grid] = index
    return index


def compact_neighbour_table(grid: Grid) -> npt.NDArray[np.int32]:
    """:func:`neighbour_table` over the free cells only (positions of :func:`free_index`;
    sentinel: the number of free cells). Cached per grid."""
    table = _COMPACT_TABLES.get(grid)
    if table is None:
        index = free_index(grid)
        m = int(grid.free.sum())
        full = neighbour_table(grid)[: grid.size][grid.free.ravel()]
        extended = np.append(index, np.int32(m))  # the sentinel size maps to the sentinel m
        table = np.vstack([extended[full], np.full((1, 4), m, dtype=np.int32)])
        table.setflags(write=False)
        _COMPACT_TABLES[grid] = table
    return table


def cell_distance_rows(grid: Grid, cells: Sequence[int]) -> npt.NDArray[np.int32]:
    """``out[k, free_index[c]]``: moves from free cell c to flat cell ``cells[k]`` (-1 if
    unreachable): :func:`distance_tables` over the free cells only (a sixth of the memory on a
    map with 17% free cells, such as brc202d). ValueError for a cell that is not free."""
    index = free_index(grid)
    for c in cells:
        if not 0 <= c < grid.size or index[c] < 0:
            raise ValueError(f"goal {grid.cell(c)} is not a free cell of {grid!r}")
    return _multi_bfs(compact_neighbour_table(grid), [[int(index[c])] for c in cells])
