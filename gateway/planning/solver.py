"""The planner's entry point: optimal CBS, with prioritised planning as an optional fallback."""

from __future__ import annotations

from collections.abc import Sequence

from gateway.planning.cbs import CBSOptions, solve_cbs
from gateway.planning.grid import Cell, Grid
from gateway.planning.plan import Deadline, NoSolution, Solution
from gateway.planning.prioritized import solve_prioritized
from gateway.planning.problem import Forbidden

__all__ = ["CBSOptions", "Forbidden", "solve", "solve_cbs", "solve_prioritized"]


def solve(
    grid: Grid,
    starts: Sequence[Cell],
    goals: Sequence[Cell],
    *,
    deadline: Deadline,
    forbidden: Sequence[Forbidden] = (),
    fallback: Deadline | None = None,
) -> Solution:
    """An SOC-optimal 1-robust plan by CBS within ``deadline``.

    If CBS runs out of time and a ``fallback`` deadline is given, a prioritised plan
    (``optimal=False``) found within ``fallback``. Raises ``NoSolution`` otherwise
    (``timed_out=True`` when it was time) and ``ValueError`` on a malformed instance.
    """
    try:
        return solve_cbs(grid, starts, goals, deadline=deadline, forbidden=forbidden)
    except NoSolution as exc:
        if not exc.timed_out or fallback is None:
            raise
    return solve_prioritized(grid, starts, goals, deadline=fallback, forbidden=forbidden)
