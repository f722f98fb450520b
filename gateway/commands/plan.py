"""``fleetgate plan``: solve one instance with the 1-robust planner and print the solution."""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Sequence
from typing import Any

from gateway.cli import EXIT_NO_SOLUTION, EXIT_OK, UsageError
from gateway.commands.deadline import WallDeadline
from gateway.commands.instance_args import (
    add_instance_arguments,
    add_motion_arguments,
    instance_from_args,
    starts_from_args,
)
from gateway.planning.instance import Instance
from gateway.planning.plan import NoSolution, Solution
from gateway.planning.problem import Place
from gateway.planning.solver import solve
from gateway.planning.validate import check_plan

DEFAULT_TIME_LIMIT = 60.0
"""Seconds the planner may take unless ``--time-limit`` says otherwise."""


def solution_json(instance: Instance, solution: Solution, runtime_s: float,
                  starts: Sequence[Place] | None = None) -> dict[str, Any]:
    """The solution object of DESIGN section 3 (``fleetgate plan --json``).

    Under ``turning`` path entries and ``starts`` (the planner's, with headings) are
    ``[x, y, heading]``; goals are ``[x, y]`` (any final heading).
    """
    plan = solution.plan
    return {
        "map": instance.grid.name,
        "motion": plan.motion,
        "robust": 1,
        "optimal": solution.optimal,
        "soc": plan.soc,
        "makespan": plan.makespan,
        "runtime_s": round(runtime_s, 6),
        "expanded_nodes": solution.expanded_nodes,
        "agents": [{"start": list(s), "goal": list(g), "path": path}
                   for s, g, path in zip(starts or instance.starts, instance.goals,
                                         plan.json_paths(), strict=True)],
    }


def _plan(args: argparse.Namespace) -> int:
    for flag, value in (("--time-limit", args.time_limit), ("--fallback", args.fallback)):
        if value is not None and value <= 0:
            raise UsageError(f"{flag} must be positive, got {value}")
    instance = instance_from_args(args)
    starts = starts_from_args(args, instance)
    deadline = WallDeadline(args.time_limit)
    fallback = WallDeadline(args.time_limit + args.fallback) if args.fallback else None
    try:
        solution = solve(instance.grid, starts, instance.goals, deadline=deadline,
                         fallback=fallback, motion=args.motion)
    except NoSolution as exc:
        runtime = deadline.elapsed()
        limit = args.time_limit + (args.fallback or 0.0)
        why = (f"no solution within the time limit of {limit:g} s" if exc.timed_out
               else f"no solution: {exc}")
        print(f"fleetgate: {why} ({runtime:.3f} s)", file=sys.stderr)
        return EXIT_NO_SOLUTION
    runtime = deadline.elapsed()
    check_plan(instance.grid, starts, instance.goals, solution.plan)
    if args.json:
        print(json.dumps(solution_json(instance, solution, runtime, starts)))
    else:
        quality = "optimal" if solution.optimal else "not proven optimal"
        turning = ", turning" if args.motion == "turning" else ""
        print(f"{instance.grid.name or 'map'}, {instance.num_agents} agents{turning}: "
              f"SOC {solution.plan.soc}, makespan {solution.plan.makespan} ({quality}), "
              f"{solution.expanded_nodes} nodes expanded in {runtime:.3f} s")
    return EXIT_OK


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    """Add ``fleetgate plan``."""
    parser = sub.add_parser(
        "plan", help="solve a MAPF instance (1-robust, sum-of-costs optimal)",
        description="Find a 1-robust plan for the first N agents of a scenario (or a mapf-IR "
                    "instance). Exit 2 on bad input, 3 when no solution is found in time.")
    add_instance_arguments(parser)
    add_motion_arguments(parser, default="omni")
    parser.add_argument("--json", action="store_true",
                        help="print the solution as JSON (map, soc, makespan, agents' paths...)")
    parser.add_argument("--time-limit", type=float, default=DEFAULT_TIME_LIMIT, metavar="SEC",
                        help=f"give up after SEC seconds of wall time "
                             f"(default {DEFAULT_TIME_LIMIT:g})")
    parser.add_argument("--fallback", type=float, default=None, metavar="SEC",
                        help="if CBS runs out of time, spend up to SEC more seconds on the fast "
                             "prioritised planner (the output then says \"optimal\": false)")
    parser.set_defaults(func=_plan)
