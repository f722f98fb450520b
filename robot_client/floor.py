"""The floor grid the robots drive on: cells, metres, headings and AprilTag ids.

World frame (metres, right-handed, z up): x grows with the grid column and y grows towards
*decreasing* rows ("north"), so the floor seen from above looks like the map drawn with row 0
at the top. The centre of cell ``(col, row)`` is ``(col * cell, -row * cell)``. Headings are
counter-clockwise from +x: E = 0, N = pi/2, W = pi, S = -pi/2.

One AprilTag (36h11 family) lies at the centre of every cell, upright when seen with north up,
with id ``row * width + col``; ``tag_size_m`` is the side of its black square.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from protocol.messages import Heading

HEADING_ANGLE: dict[Heading, float] = {"E": 0.0, "N": math.pi / 2, "W": math.pi, "S": -math.pi / 2}
_STEP: dict[Heading, tuple[int, int]] = {"E": (1, 0), "N": (0, -1), "W": (-1, 0), "S": (0, 1)}

Cell = tuple[int, int]


def nearest_heading(theta: float) -> Heading:
    """The compass heading closest to angle ``theta``."""
    k = round(theta / (math.pi / 2)) % 4
    headings: tuple[Heading, ...] = ("E", "N", "W", "S")
    return headings[k]


def heading_of_step(src: Cell, dst: Cell) -> Heading:
    """The heading of a move from ``src`` to its 4-neighbour ``dst`` (ValueError otherwise)."""
    step = (dst[0] - src[0], dst[1] - src[1])
    for h, s in _STEP.items():
        if s == step:
            return h
    raise ValueError(f"{list(src)} -> {list(dst)} is not a move to a 4-neighbour")


@dataclass(frozen=True, slots=True)
class FloorGrid:
    """Geometry of the tag grid: ``width`` x ``height`` cells of ``cell_m`` metres."""

    width: int
    height: int
    cell_m: float = 0.4
    tag_size_m: float = 0.12

    def __post_init__(self) -> None:
        if self.width < 1 or self.height < 1:
            raise ValueError(f"grid must have at least one cell, got {self.width}x{self.height}")
        if not 0 < self.tag_size_m < self.cell_m:
            raise ValueError(f"tag size {self.tag_size_m} m must be in (0, cell {self.cell_m} m)")

    def centre(self, cell: Cell) -> tuple[float, float]:
        """World coordinates of the centre of ``cell``."""
        return cell[0] * self.cell_m, -cell[1] * self.cell_m

    def cell_at(self, x: float, y: float) -> Cell:
        """The cell whose square contains world point (x, y) (may lie outside the grid)."""
        return round(x / self.cell_m), round(-y / self.cell_m)

    def contains(self, cell: Cell) -> bool:
        """Whether ``cell`` is on the grid."""
        return 0 <= cell[0] < self.width and 0 <= cell[1] < self.height

    def tag_id(self, cell: Cell) -> int:
        """Id of the tag lying on ``cell``."""
        if not self.contains(cell):
            raise ValueError(f"cell {list(cell)} is outside the {self.width}x{self.height} grid")
        return cell[1] * self.width + cell[0]

    def tag_cell(self, tag_id: int) -> Cell | None:
        """The cell tag ``tag_id`` lies on, or None if no tag of the grid has that id."""
        if not 0 <= tag_id < self.width * self.height:
            return None
        return tag_id % self.width, tag_id // self.width

    def tag_corners(self, tag_id: int) -> list[tuple[float, float]]:
        """World coordinates of the tag's corners in detector order: top-left, top-right,
        bottom-right, bottom-left of the upright tag (top = north)."""
        cell = self.tag_cell(tag_id)
        if cell is None:
            raise ValueError(f"tag {tag_id} is not part of the grid")
        cx, cy = self.centre(cell)
        h = self.tag_size_m / 2
        return [(cx - h, cy + h), (cx + h, cy + h), (cx + h, cy - h), (cx - h, cy - h)]
