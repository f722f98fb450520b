"""The simulated floor: which robot (or the intruder) stands on which cell.

A robot holds its cell; while it moves it holds both its source and its target. The intruder
holds one cell while it is present. Simulated robots and the intruder look here before they
enter a cell; the world itself only records, so a second occupant of a cell (which the
protocol of its users should make impossible) is counted as a collision rather than refused.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

from gateway.planning.grid import Cell

INTRUDER = -1
"""Occupant id of the intruder; robots are 0..n-1."""


@dataclass(frozen=True, slots=True)
class Collision:
    """``newcomer`` entered ``cell`` at ``t_ms`` while ``holders`` were on it."""

    t_ms: float
    cell: Cell
    newcomer: int
    holders: tuple[int, ...]


class World:
    """Cell occupancy of robots and the intruder."""

    def __init__(self, robot_cells: Sequence[Cell] = ()) -> None:
        self._holders: dict[Cell, list[int]] = {}
        self.collisions: list[Collision] = []
        for robot, cell in enumerate(robot_cells):
            self.occupy(cell, robot, 0.0)

    def is_free(self, cell: Cell) -> bool:
        """True if nobody (no robot, no intruder) is on ``cell``."""
        return cell not in self._holders

    def holders(self, cell: Cell) -> tuple[int, ...]:
        """Who is on ``cell`` (robot ids, :data:`INTRUDER`), in order of arrival."""
        return tuple(self._holders.get(cell, ()))

    def occupy(self, cell: Cell, who: int, t_ms: float) -> None:
        """``who`` enters ``cell`` at ``t_ms``; a taken cell records a :class:`Collision`."""
        holders = self._holders.get(cell)
        if holders is None:
            self._holders[cell] = [who]
            return
        if who in holders:
            raise ValueError(f"occupant {who} is already on {cell}")
        self.collisions.append(Collision(t_ms, cell, who, tuple(holders)))
        holders.append(who)

    def release(self, cell: Cell, who: int) -> None:
        """``who`` leaves ``cell``; raises ValueError if it was not there."""
        holders = self._holders.get(cell)
        if holders is None or who not in holders:
            raise ValueError(f"occupant {who} is not on {cell}")
        holders.remove(who)
        if not holders:
            del self._holders[cell]
