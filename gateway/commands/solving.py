"""Planning for the commands that make plans (plan, simulate, demo): ``--time-limit`` and
``--fallback``, a live "planning ..." status while CBS works, and one message when the
prioritised planner's plan is used instead of an optimal one."""

from __future__ import annotations

import argparse
from typing import TYPE_CHECKING

from gateway.commands.progress import StatusLine, ticking
from gateway.runtime.exits import UsageError

if TYPE_CHECKING:
    from collections.abc import Sequence

    from gateway.planning.instance import Instance
    from gateway.planning.motion import Motion
    from gateway.planning.plan import Solution
    from gateway.planning.problem import Place


def add_planning_arguments(parser: argparse.ArgumentParser, time_limit_s: float) -> None:
    """Add ``--time-limit SEC`` (default ``time_limit_s``) and ``--fallback SEC``."""
    parser.add_argument("--time-limit", type=float, default=time_limit_s, metavar="SEC",
                        help=f"give CBS up to SEC seconds of wall time per solve "
                             f"(default {time_limit_s:g})")
    parser.add_argument("--fallback", type=float, default=None, metavar="SEC",
                        help="if CBS runs out of time, spend up to SEC more seconds on the fast "
                             "prioritised planner (a feasible, not optimal plan)")


def check_planning_arguments(args: argparse.Namespace) -> None:
    """Raise :class:`UsageError` unless ``--time-limit`` and ``--fallback`` are positive."""
    for flag, value in (("--time-limit", args.time_limit), ("--fallback", args.fallback)):
        if value is not None and value <= 0:
            raise UsageError(f"{flag} must be positive, got {value:g}")


def no_solution_message(instance: Instance, args: argparse.Namespace, reason: str,
                        timed_out: bool) -> str:
    """The one line printed when no plan was found (the command then exits 3)."""
    name = instance.name or "the instance"
    if not timed_out:
        return f"no solution for {name}: {reason}"
    limit = args.time_limit + (args.fallback or 0.0)
    hint = "" if args.fallback else "; try --fallback SEC (a prioritised, not optimal plan)"
    return f"no solution for {name} within the time limit of {limit:g} s{hint}"


def solve_instance(instance: Instance, args: argparse.Namespace,
                   status: StatusLine | None = None, *, motion: Motion = "omni",
                   starts: Sequence[Place] | None = None) -> Solution:
    """Plan ``instance`` with the options' time limit and fallback; raises ``NoSolution``.

    ``starts`` replace the instance's (``(x, y, heading)`` under ``motion="turning"``).

    While CBS works a terminal shows "planning NAME (N agents) ... 3 s"; a fallback plan is
    announced in one line on ``status``.
    """
    from gateway.planning.solver import solve
    from gateway.runtime.deadline import WallDeadline

    status = status or StatusLine()
    name = instance.name or "the instance"
    deadline = WallDeadline(args.time_limit)
    fallback = WallDeadline(args.time_limit + args.fallback) if args.fallback else None
    with ticking(status, lambda s: f"planning {name} ({instance.num_agents} agents) ... "
                                   f"{s:.0f} s of {args.time_limit:g} s"):
        solution = solve(instance.grid, starts or instance.starts, instance.goals,
                         deadline=deadline, fallback=fallback, motion=motion)
    if not solution.optimal:
        status.print(f"fleetgate: no optimal plan for {name} within {args.time_limit:g} s; "
                     f"using the prioritised planner's plan (SOC {solution.plan.soc}, not "
                     f"proven optimal)")
    return solution
