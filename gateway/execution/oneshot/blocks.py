"""Cells the fleet reported blocked, and how long each block is expected to last (sans-I/O).

A robot that waits for a cell no robot is planned to hold (its ``blocked`` report: the cell is
taken by something the plan does not know) opens a block on that cell. The block is watched as
long as some robot waits for it, and clears when a robot reports ``unblocked`` for it or moves
into it. Once nobody waits for it (the replan cancelled the waiting robot), its last sighting
stays what it was: the estimate stops growing, and when its expected end has passed it is no
longer an obstacle, so a later plan may send a robot through and find out. Informed replanning
(``Executor(informed=True)``) hands the open blocks to the planner as obstacles until their
estimated end; it never learns the simulator's ground truth.

The estimate uses only what the fleet saw. A block seen for ``e`` ms (from its opening to its
last sighting) is expected to last
as long as the earlier blocks that lasted longer than ``e`` did on average (their mean
duration), or, with no such earlier block, ``2 e`` (a block seen for ``e`` is as likely to end
before ``2 e`` as after: the median under a scale-free prior), and never less than
``min_ms`` in all.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from gateway.planning.grid import Cell


@dataclass
class BlockTracker:
    """Open blocks by cell (since when) and the durations of the blocks that cleared."""

    min_ms: float = 1000.0
    """The shortest duration a block is expected to last (one action)."""
    open: dict[Cell, float] = field(default_factory=dict)
    """Open blocks: since when."""
    seen: dict[Cell, float] = field(default_factory=dict)
    """Open blocks: when a robot last found the cell still taken."""
    history: list[float] = field(default_factory=list)

    def opened(self, cell: Cell, now_ms: float) -> None:
        """A robot waits for ``cell``, which no robot is planned to hold (a second report on
        an open block keeps its start)."""
        self.open.setdefault(cell, now_ms)
        self.seen[cell] = now_ms

    def still_blocked(self, cell: Cell, now_ms: float) -> None:
        """A robot still waits for ``cell`` at ``now_ms``."""
        if cell in self.open:
            self.seen[cell] = now_ms

    def cleared(self, cell: Cell, now_ms: float) -> None:
        """``cell`` is free again (unblocked, or a robot moved into it); its duration is
        remembered for later estimates."""
        since = self.open.pop(cell, None)
        if since is not None:
            del self.seen[cell]
            self.history.append(now_ms - since)

    def expected_end_ms(self, cell: Cell) -> float:
        """When the open block on ``cell`` is expected to clear."""
        since = self.open[cell]
        lasted = self.seen[cell] - since
        longer = [d for d in self.history if d > lasted]
        total = sum(longer) / len(longer) if longer else 2.0 * lasted
        return since + max(total, self.min_ms, lasted)

    def unsupported(self, cell: Cell) -> bool:
        """True if no earlier block lasted longer than the open one on ``cell`` has been seen:
        its expected end is the ``2 e`` guess, not what earlier blocks did."""
        lasted = self.seen[cell] - self.open[cell]
        return not any(d > lasted for d in self.history)

    def obstacles(self, now_ms: float) -> tuple[tuple[Cell, float], ...]:
        """Every open block expected to last beyond ``now_ms``, as ``(cell, expected end)``,
        in cell order."""
        ends = ((c, self.expected_end_ms(c)) for c in sorted(self.open))
        return tuple((c, end) for c, end in ends if end > now_ms)
