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

Beside that point estimate, the block's duration as a distribution (:meth:`BlockTracker.
end_quantiles`, what risk-aware shadow planning weighs): the history conditioned on how long
the block has lasted, as a predictive distribution that does not trust a short history more
than it deserves (Hill's A(n)): with ``n`` earlier blocks that lasted longer than ``e``, sorted
``d_1 <= ... <= d_n``, the block ends in each of the ``n + 1`` gaps ``(e, d_1)``, ``(d_1, d_2)``,
..., ``(d_n, inf)`` with probability ``1 / (n + 1)``, uniformly within a gap, and beyond
``d_n`` as the scale-free prior says (``P(D > x | D > d_n) = d_n / x``; with no such block,
beyond ``e``: as likely to end before ``2 e`` as after). No block lasts less than ``min_ms``.
"""

from __future__ import annotations

from collections.abc import Sequence
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

    def end_quantiles(self, cell: Cell, levels: Sequence[float]) -> list[float]:
        """When the open block on ``cell`` ends at each probability level of ``levels`` (the
        quantiles of its end time; see the module's docstring)."""
        since = self.open[cell]
        lasted = self.seen[cell] - since
        return [since + d for d in duration_quantiles(self.history, lasted, self.min_ms,
                                                      levels)]

    def evidence(self, cell: Cell) -> int:
        """How many earlier blocks lasted longer than the open block on ``cell`` has so far:
        the observations its duration's distribution rests on (beyond them, the prior)."""
        lasted = self.seen[cell] - self.open[cell]
        return sum(1 for d in self.history if d > lasted)

    def obstacles(self, now_ms: float) -> tuple[tuple[Cell, float], ...]:
        """Every open block expected to last beyond ``now_ms``, as ``(cell, expected end)``,
        in cell order."""
        ends = ((c, self.expected_end_ms(c)) for c in sorted(self.open))
        return tuple((c, end) for c, end in ends if end > now_ms)


def duration_quantiles(history: Sequence[float], lasted: float, min_ms: float,
                       levels: Sequence[float]) -> list[float]:
    """A block's total duration at each probability level of ``levels`` (0 <= level < 1)
    given it has lasted ``lasted`` ms and the earlier blocks lasted ``history`` (see the
    module's docstring); at least ``lasted`` and ``min_ms``."""
    longer = sorted(d for d in history if d > lasted)
    edges = [lasted, *longer]
    gaps = len(longer) + 1
    out = []
    for q in levels:
        at = min(max(q, 0.0), 1.0 - 1e-12) * gaps
        i = int(at)
        f = at - i
        if i < len(longer):
            value = edges[i] + f * (edges[i + 1] - edges[i])
        else:
            value = edges[-1] / (1.0 - f)
        out.append(max(value, lasted, min_ms))
    return out
