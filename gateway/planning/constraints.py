"""Vertex constraints over time ranges, the only constraint kind 1-robust planning needs.

Under the 1-robust rule every conflict is "two agents in the same cell at times at most one
apart", so both CBS branches and the prioritised planner's reservations are sets of forbidden
``(cell, time)`` pairs. A constraint ``(cell, t0, t1)`` forbids the cell during ``[t0, t1]``;
``t1 = INF`` forbids it for ever from ``t0``.
"""

from __future__ import annotations

from collections.abc import Container, Iterable
from dataclasses import dataclass

INF = 1 << 30
"""An open upper end of a time range."""

Constraint = tuple[int, int, int]
"""``(cell id, t0, t1)``: the cell is forbidden at every timestep in ``[t0, t1]``; or
``(FINISH, t, t)``: the agent may not arrive on its goal for good at or before t (it may still
pass over its goal earlier)."""

FINISH = -1
"""The "cell" of a constraint on when the agent finishes rather than where it is."""


@dataclass(slots=True)
class ConstraintTable:
    """Forbidden ``(cell, time)`` pairs for one agent, in the form the low level probes.

    ``blocked`` holds keys ``t * size + cell`` of finite ranges; ``permanent[cell]`` is the
    first timestep from which a cell is forbidden for ever; ``horizon`` is a time after which
    nothing changes any more (so the low level may merge states by cell); ``last_blocked[cell]``
    is the latest finite timestep at which the cell is forbidden; the agent may not finish at or
    before ``min_finish``.
    """

    size: int
    blocked: Container[int]
    permanent: dict[int, int]
    last_blocked: dict[int, int]
    horizon: int
    min_finish: int = -1

    def goal_block(self, goal: int) -> int:
        """Latest timestep at which ``goal`` is forbidden (INF if for ever, -1 if never).

        An agent may end its path on ``goal`` at time T only if ``T > goal_block(goal)`` (this
        includes its ``min_finish``).
        """
        if goal in self.permanent:
            return INF
        return max(self.last_blocked.get(goal, -1), self.min_finish)

    def forbids(self, cell: int, t: int) -> bool:
        """True if ``cell`` is forbidden at timestep ``t``."""
        first = self.permanent.get(cell)
        if first is not None and t >= first:
            return True
        return t * self.size + cell in self.blocked


def build_table(size: int, constraints: Iterable[Constraint]) -> ConstraintTable:
    """Compile constraints on an agent into a :class:`ConstraintTable`."""
    blocked: set[int] = set()
    permanent: dict[int, int] = {}
    last_blocked: dict[int, int] = {}
    horizon = 0
    min_finish = -1
    for cell, t0, t1 in constraints:
        if cell == FINISH:
            min_finish = max(min_finish, t0)
            horizon = max(horizon, t0)
            continue
        if t0 < 0 or t1 < t0:
            raise ValueError(f"bad time range [{t0}, {t1}] on cell {cell}")
        if t1 >= INF:
            if t0 < permanent.get(cell, INF):
                permanent[cell] = t0
            horizon = max(horizon, t0)
            continue
        for t in range(t0, t1 + 1):
            blocked.add(t * size + cell)
        if t1 > last_blocked.get(cell, -1):
            last_blocked[cell] = t1
        horizon = max(horizon, t1)
    return ConstraintTable(size, blocked, permanent, last_blocked, horizon + 1, min_finish)
