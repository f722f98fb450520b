"""The planner's entry point: optimal CBS, with prioritised planning as an optional fallback."""

from __future__ import annotations

from collections.abc import Sequence

from gateway.planning.cbs import CBSOptions, solve_cbs
from gateway.planning.grid import Grid
from gateway.planning.motion import Motion
from gateway.planning.plan import Deadline, NoSolution, Solution
from gateway.planning.prioritized import solve_prioritized
from gateway.planning.problem import Forbidden, Place

__all__ = ["CBSOptions", "Forbidden", "Place", "solve", "solve_cbs", "solve_prioritized"]


def solve(
    grid: Grid,
    starts: Sequence[Place],
    goals: Sequence[Place],
    *,
    deadline: Deadline,
    forbidden: Sequence[Forbidden] = (),
    fallback: Deadline | None = None,
    motion: Motion = "omni",
) -> Solution:
    """An SOC-optimal 1-robust plan by CBS within ``deadline``.

    Under ``motion="turning"`` starts are ``(x, y, heading)`` (any configuration, e.g. robots
    stopped mid-run) and goals ``(x, y)`` or ``(x, y, heading)``.

    If CBS runs out of time and a ``fallback`` deadline is given, a prioritised plan
    (``optimal=False``) found within ``fallback``. Raises ``NoSolution`` otherwise
    (``timed_out=True`` when it was time) and ``ValueError`` on a malformed instance.
    """
    try:
        return solve_cbs(grid, starts, goals, deadline=deadline, forbidden=forbidden,
                         motion=motion)
    except NoSolution as exc:
        if not exc.timed_out or fallback is None:
            raise
    return solve_prioritized(grid, starts, goals, deadline=fallback, forbidden=forbidden,
                             motion=motion)
