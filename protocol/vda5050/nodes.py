"""Grid cells as VDA 5050 nodes: where a cell is in metres and which way a heading points.

The map frame is the standard's (section 6.7): x to the right, y up, theta counter-clockwise
from +x in radians. A cell ``(x, y)`` (x the column, y the row counted downwards, as in
MovingAI files) has its centre at ``(origin_x + (x + 0.5) * size, origin_y - (y + 0.5) *
size)``: the origin is the grid's top-left corner (set ``origin_y`` to rows x size for
non-negative coordinates). Plan headings (0 east (+x), 1 south, 2 west, 3 north) become theta
0, -pi/2, pi and pi/2.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from protocol.messages import Heading
from protocol.vda5050.models import NodePosition

THETA: dict[Heading, float] = {"E": 0.0, "S": -math.pi / 2, "W": math.pi, "N": math.pi / 2}
"""The node orientation of each compass heading."""


def heading_of(theta: float) -> Heading:
    """The compass heading nearest to ``theta`` (radians)."""
    return min(THETA, key=lambda h: abs(math.remainder(theta - THETA[h], 2 * math.pi)))


@dataclass(frozen=True, slots=True)
class NodeMap:
    """Grid cells as nodes on map ``map_id`` (cells of ``cell_m`` metres)."""

    cell_m: float
    map_id: str
    origin_x: float = 0.0
    origin_y: float = 0.0

    def __post_init__(self) -> None:
        if not (self.cell_m > 0 and math.isfinite(self.cell_m)):
            raise ValueError(f"cell size must be a positive number of metres, got {self.cell_m}")

    def node_id(self, cell: tuple[int, int]) -> str:
        """The node id of ``cell``: ``"n<x>_<y>"``."""
        return f"n{cell[0]}_{cell[1]}"

    def edge_id(self, src: tuple[int, int], dst: tuple[int, int]) -> str:
        """The edge id from ``src`` to ``dst`` (the same cell for a turn or a wait)."""
        return f"e{src[0]}_{src[1]}_{dst[0]}_{dst[1]}"

    def position(self, cell: tuple[int, int], heading: Heading | None) -> NodePosition:
        """The node position of ``cell``; ``theta`` only when the motion model has headings."""
        return NodePosition(x=self.origin_x + (cell[0] + 0.5) * self.cell_m,
                            y=self.origin_y - (cell[1] + 0.5) * self.cell_m,
                            theta=None if heading is None else THETA[heading],
                            map_id=self.map_id)

    def cell_of(self, x: float, y: float) -> tuple[int, int]:
        """The cell that contains the point ``(x, y)`` of the map."""
        return (math.floor((x - self.origin_x) / self.cell_m),
                math.floor((self.origin_y - y) / self.cell_m))
