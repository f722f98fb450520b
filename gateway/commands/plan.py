"""``fleetgate plan``: solve one instance with the 1-robust planner and print the solution."""

from __future__ import annotations

import argparse
import json
import sys
import time
from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

from gateway.commands.instance_args import add_instance_arguments, add_motion_arguments
from gateway.commands.solving import (
    add_planning_arguments,
    check_planning_arguments,
    no_solution_message,
    solve_instance,
)
from gateway.runtime.exits import EXIT_NO_SOLUTION, EXIT_OK

if TYPE_CHECKING:
    from gateway.planning.instance import Instance
    from gateway.planning.plan import Solution
    from gateway.planning.problem import Place

DEFAULT_TIME_LIMIT = 60.0
"""Seconds the planner may take unless ``--time-limit`` says otherwise."""


def solution_json(instance: Instance, solution: Solution, runtime_s: float,
                  starts: Sequence[Place] | None = None) -> dict[str, Any]:
    """The solution object of DESIGN section 3 (``fleetgate plan --json``); ``starts`` are
    the planner's (``(x, y, heading)`` under ``turning``)."""
    from gateway.planning.solution_json import SolutionJson

    return SolutionJson(instance.grid.name, tuple(starts or instance.starts),
                        tuple(instance.goals), solution.plan, solution.optimal, runtime_s,
                        solution.expanded_nodes).to_json()


def _plan(args: argparse.Namespace) -> int:
    from gateway.commands.instance_args import instance_from_args, starts_from_args
    from gateway.planning.plan import NoSolution
    from gateway.planning.validate import check_plan

    check_planning_arguments(args)
    instance = instance_from_args(args)
    starts = starts_from_args(args, instance)
    began = time.monotonic()
    try:
        solution = solve_instance(instance, args, starts=starts, motion=args.motion)
    except NoSolution as exc:
        why = no_solution_message(instance, args, str(exc), exc.timed_out)
        print(f"fleetgate: {why} ({time.monotonic() - began:.3f} s)", file=sys.stderr)
        return EXIT_NO_SOLUTION
    runtime = time.monotonic() - began
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
    add_planning_arguments(parser, DEFAULT_TIME_LIMIT)
    parser.set_defaults(func=_plan)
