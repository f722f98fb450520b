"""Connected components of a grid's free cells (4-connected).

A plain breadth-first labelling over :meth:`Grid.neighbour_ids`: linear in the number of cells
and cheap to import (scipy.ndimage would add about a second to every command's start-up).
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from gateway.planning.grid import Grid


def component_labels(grid: Grid) -> npt.NDArray[np.int32]:
    """``labels[y, x]``: the 4-connected component (1, 2, ...) of each free cell, 0 for
    obstacles. Components are numbered in row-major order of their first cell."""
    labels = [0] * grid.size
    current = 0
    for seed in np.flatnonzero(grid.free.ravel()).tolist():
        if labels[seed]:
            continue
        current += 1
        labels[seed] = current
        frontier = [seed]
        while frontier:
            cell = frontier.pop()
            for nxt in grid.neighbour_ids(cell):
                if not labels[nxt]:
                    labels[nxt] = current
                    frontier.append(nxt)
    return np.array(labels, dtype=np.int32).reshape(grid.height, grid.width)


def largest_component(grid: Grid) -> npt.NDArray[np.bool_]:
    """The mask (``[y, x]``) of the grid's largest 4-connected component (the first one on a
    tie; all False if no cell is free)."""
    labels = component_labels(grid)
    sizes = np.bincount(labels.ravel())
    if sizes.size <= 1:
        return np.zeros(labels.shape, dtype=bool)
    sizes[0] = 0
    return np.asarray(labels == int(np.argmax(sizes)), dtype=bool)


def is_connected(grid: Grid) -> bool:
    """True if the free cells form exactly one 4-connected component."""
    return int(component_labels(grid).max()) == 1
