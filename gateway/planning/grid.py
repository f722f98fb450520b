"""The 4-connected grid that every plan lives on."""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

Cell = tuple[int, int]
"""A grid cell as ``(x, y)``: x is the column, y the row, as in MovingAI ``.scen`` files."""

MOVES: tuple[Cell, ...] = ((1, 0), (-1, 0), (0, 1), (0, -1))
"""The four unit moves of the ``omni`` motion model (a wait is the fifth action)."""


@dataclass(frozen=True, eq=False)
class Grid:
    """A rectangular map; ``free[y, x]`` is True where a robot may stand.

    Cells are addressed as ``(x, y)``; ``index(cell)`` gives the flat id ``y * width + x`` that
    the planner's numpy tables use.
    """

    free: npt.NDArray[np.bool_]
    name: str = ""
    _neighbours: tuple[tuple[int, ...], ...] = field(init=False, repr=False)

    def __post_init__(self) -> None:
        free = np.ascontiguousarray(self.free, dtype=bool)
        if free.ndim != 2 or free.shape[0] == 0 or free.shape[1] == 0:
            raise ValueError(f"grid must be a non-empty 2-D array, got shape {free.shape}")
        free.setflags(write=False)
        object.__setattr__(self, "free", free)
        h, w = free.shape
        flat = free.ravel()
        neighbours: list[tuple[int, ...]] = []
        for i in range(h * w):
            if not flat[i]:
                neighbours.append(())
                continue
            x, y = i % w, i // w
            out = []
            for dx, dy in MOVES:
                nx, ny = x + dx, y + dy
                if 0 <= nx < w and 0 <= ny < h and flat[ny * w + nx]:
                    out.append(ny * w + nx)
            neighbours.append(tuple(out))
        object.__setattr__(self, "_neighbours", tuple(neighbours))

    @property
    def width(self) -> int:
        """Number of columns."""
        return int(self.free.shape[1])

    @property
    def height(self) -> int:
        """Number of rows."""
        return int(self.free.shape[0])

    @property
    def size(self) -> int:
        """Number of cells, free or not."""
        return self.width * self.height

    def in_bounds(self, cell: Cell) -> bool:
        """True if ``cell`` lies inside the map."""
        x, y = cell
        return 0 <= x < self.width and 0 <= y < self.height

    def is_free(self, cell: Cell) -> bool:
        """True if ``cell`` is inside the map and not an obstacle."""
        return self.in_bounds(cell) and bool(self.free[cell[1], cell[0]])

    def index(self, cell: Cell) -> int:
        """Flat id of a cell: ``y * width + x``."""
        return cell[1] * self.width + cell[0]

    def cell(self, index: int) -> Cell:
        """Inverse of :meth:`index`."""
        return (index % self.width, index // self.width)

    def neighbour_ids(self, index: int) -> tuple[int, ...]:
        """Flat ids of the free 4-neighbours of a free cell (empty for an obstacle)."""
        return self._neighbours[index]

    def neighbours(self, cell: Cell) -> list[Cell]:
        """Free 4-neighbours of ``cell``."""
        return [self.cell(j) for j in self._neighbours[self.index(cell)]]

    def free_cells(self) -> Iterator[Cell]:
        """All free cells, row by row."""
        ys, xs = np.nonzero(self.free)
        yield from zip(xs.tolist(), ys.tolist(), strict=True)

    def __repr__(self) -> str:
        return f"Grid({self.name!r}, {self.width}x{self.height})"
