"""Shared helpers for the planner tests: grids from text, a counting deadline, checks."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from hypothesis import strategies as st

from gateway.planning.grid import Cell, Grid
from gateway.planning.motion import HeadedCell
from gateway.planning.plan import Plan
from gateway.planning.validate import plan_violations

Forbidden = tuple[Cell, int, int]


def grid_of(*rows: str) -> Grid:
    """A grid from rows of ``.`` (free) and ``@`` (blocked)."""
    return Grid(np.array([[ch == "." for ch in row] for row in rows], dtype=bool))


class CountingDeadline:
    """Expires after ``calls`` calls of :meth:`expired` (no clock involved)."""

    def __init__(self, calls: int) -> None:
        self.left = calls

    def expired(self) -> bool:
        """True once the budget of calls is spent."""
        self.left -= 1
        return self.left < 0


def assert_valid(
    grid: Grid,
    starts: Sequence[Cell | HeadedCell],
    goals: Sequence[Cell | HeadedCell],
    plan: Plan,
    forbidden: Sequence[Forbidden] = (),
) -> None:
    """The plan passes the independent validator and keeps off every forbidden window."""
    assert plan_violations(grid, starts, goals, plan) == []
    horizon = max(len(p) for p in plan.paths) + max((t1 for _, _, t1 in forbidden), default=0)
    for k in range(len(plan.paths)):
        for t in range(horizon + 1):
            cell = plan.position(k, t)
            for c, t0, t1 in forbidden:
                assert not (c == cell and t0 <= t <= t1), (k, t, cell)


@st.composite
def small_instances(
    draw: st.DrawFn, max_w: int, max_h: int, agents: tuple[int, int], windows: bool = True
) -> tuple[Grid, list[Cell], list[Cell], list[Forbidden]]:
    """A random grid (about 20% obstacles) with distinct starts and goals and at most one
    forbidden window."""
    w = draw(st.integers(3, max_w))
    h = draw(st.integers(3, max_h))
    cells = [(x, y) for y in range(h) for x in range(w)]
    blocked = draw(st.sets(st.sampled_from(cells), max_size=len(cells) // 5))
    free = [c for c in cells if c not in blocked]
    n = draw(st.integers(*agents))
    n = min(n, len(free))
    starts = draw(st.permutations(free))[:n]
    goals = draw(st.permutations(free))[:n]
    grid = Grid(np.array([[(x, y) not in blocked for x in range(w)] for y in range(h)]))
    forbidden: list[Forbidden] = []
    if windows and draw(st.booleans()):
        t0 = draw(st.integers(1, 4))
        forbidden.append((draw(st.sampled_from(free)), t0, t0 + draw(st.integers(0, 2))))
    return grid, list(starts), list(goals), forbidden
