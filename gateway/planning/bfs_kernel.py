"""Compiled breadth-first search (numba): the kernel behind :mod:`gateway.planning.distance`.

numba rather than Cython or a C extension: it ships as wheels on PyPI for the platforms numpy
does, so ``pip install`` needs no compiler, and the kernel stays Python source. Compiled on
first use and cached on disk (``cache=True``); measured against the numpy frontier search it
replaced in ``bench/distance.py``. :func:`pack_mod3` packs tables into the planner's compact
form (:func:`gateway.planning.pibt.compact_rows`: 0.4 ms a table of 586,660 cells, 13 ms in
numpy).
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt
from numba import njit


@njit(cache=True, nogil=True)
def bfs_groups(table: npt.NDArray[np.int32], sources: npt.NDArray[np.int64],
               bounds: npt.NDArray[np.int64], out: npt.NDArray[np.int32]) -> None:
    """Fill ``out[k]`` with the breadth-first distances from the group of sources
    ``sources[bounds[k]:bounds[k + 1]]`` over the graph of ``table`` (-1: not reached).

    ``table`` is ``(n + 1, d)``: row i lists the nodes one step from node i (towards the
    sources), padded with the sentinel n. ``out`` is ``(groups, n)`` and must hold -1.
    """
    n = table.shape[0] - 1
    width = table.shape[1]
    queue = np.empty(n, dtype=np.int64)
    for k in range(bounds.shape[0] - 1):
        row = out[k]
        head = 0
        tail = 0
        for i in range(bounds[k], bounds[k + 1]):
            s = sources[i]
            if row[s] < 0:
                row[s] = 0
                queue[tail] = s
                tail += 1
        while head < tail:
            v = queue[head]
            head += 1
            nd = row[v] + 1
            for j in range(width):
                u = table[v, j]
                if u < n and row[u] < 0:
                    row[u] = nd
                    queue[tail] = u
                    tail += 1


@njit(cache=True, nogil=True)
def pack_mod3(found: npt.NDArray[np.int32], out: npt.NDArray[np.uint8]) -> None:
    """Fill ``out[k]`` (zeros, ``ceil(n / 4)`` bytes a row) with ``found[k]``'s entries in 2
    bits each, four a byte from the lowest bits up: the entry modulo 3, or 3 where it is
    negative (unreachable) and in the padding."""
    rows, n = found.shape
    for k in range(rows):
        for i in range(n):
            d = found[k, i]
            code = 3 if d < 0 else d % 3
            out[k, i >> 2] |= np.uint8(code << ((i & 3) << 1))
        for i in range(n, 4 * out.shape[1]):
            out[k, i >> 2] |= np.uint8(3 << ((i & 3) << 1))
