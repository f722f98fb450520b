"""``fleetgate simulate``: one simulated execution in virtual time (DESIGN section 3)."""

from __future__ import annotations

import argparse
import json
import sys
from typing import TYPE_CHECKING

from gateway.commands.instance_args import add_instance_arguments, add_motion_arguments
from gateway.commands.progress import StatusLine, ticking
from gateway.commands.solving import (
    add_planning_arguments,
    check_planning_arguments,
    no_solution_message,
    solve_instance,
)
from gateway.execution.oneshot.policies import AUTONOMOUS_POLICIES
from gateway.execution.params import INTRUDER_READINGS, PAPER
from gateway.runtime.exits import EXIT_NO_SOLUTION, EXIT_OK, UsageError
from sim_clients.stays import STAY_HELP

if TYPE_CHECKING:
    from sim_clients.des import SolverTime

def _solver_time(text: str) -> SolverTime:
    from sim_clients.des import parse_solver_time  # when parsing a command, not for --help

    try:
        return parse_solver_time(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def _run(args: argparse.Namespace) -> int:
    from gateway.commands.instance_args import instance_from_args, starts_from_args
    from gateway.planning.plan import NoSolution
    from gateway.runtime.trace import JsonlWriter
    from sim_clients.des import SimConfig, run_simulation
    from sim_clients.intruder import IntruderConfig
    from sim_clients.stays import stay_option

    if args.threshold_ms < 0:
        raise UsageError(f"--threshold-ms must be >= 0, got {args.threshold_ms:g}")
    stay_option(args.intruder_stay)  # bad input before planning
    check_planning_arguments(args)
    instance = instance_from_args(args)
    starts = starts_from_args(args, instance)
    status = StatusLine()
    try:
        solution = solve_instance(instance, args, status, motion=args.motion, starts=starts)
    except NoSolution as exc:
        why = no_solution_message(instance, args, str(exc), exc.timed_out)
        print(f"fleetgate: {why}", file=sys.stderr)
        return EXIT_NO_SOLUTION
    writer = JsonlWriter(args.trace) if args.trace else None
    stay = stay_option(args.intruder_stay)
    config = SimConfig(instance.grid, solution.plan, seed=args.seed, intruder=args.intruder,
                       policy=args.policy, threshold_ms=args.threshold_ms,
                       solver_time=args.solver_time, solver_time_limit_s=args.time_limit,
                       trace=writer, informed=args.informed,
                       intruder_config=IntruderConfig(reading=args.intruder_reading),
                       intruder_stay=stay)
    try:
        with ticking(status, lambda s: f"simulating {instance.num_agents} robots ... {s:.0f} s"):
            result = run_simulation(config)
    except BaseException as exc:
        if writer is not None:
            writer.close(exc)
        raise
    if writer is not None:
        writer.close()
    if args.json:
        print(json.dumps(result.summary()))
        return EXIT_OK
    replan = (f"replanned at {result.replan_at_ms:.0f} ms (solver {result.solver_ms:.0f} ms)"
              if result.replan_at_ms is not None else "no replan")
    intruder = (f"intruder on {result.intruder_cell} from {result.intruder_on_ms:.0f} ms"
                if result.intruder_cell is not None else "no intruder in the way"
                if args.intruder else "no intruder")
    print(f"{instance.name}: {instance.num_agents} robots ({args.motion}), plan SOC "
          f"{result.plan_soc} (makespan {result.plan_makespan})")
    print(f"executed SOC {result.soc_ms:.0f} ms, makespan {result.makespan_ms:.0f} ms; "
          f"{intruder}; {replan}; collisions {result.collisions}")
    return EXIT_OK


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    """Add ``fleetgate simulate``."""
    p = sub.add_parser(
        "simulate", help="one simulated execution in virtual time",
        description="Plan the instance, then execute the plan with simulated robots in virtual "
                    "time (every action 1000 ms), optionally with the intruder and a replanning "
                    "policy. Exit codes: 0 success, 2 bad input, 3 no plan within the limit.")
    add_instance_arguments(p)
    add_motion_arguments(p, default="omni")
    p.add_argument("--seed", metavar="K", type=int, default=0,
                   help="seed of the intruder's choice and the random policy (default 0)")
    p.add_argument("--intruder", action=argparse.BooleanOptionalAction, default=True,
                   help=f"the intruder appears at {PAPER.intruder_appear_ms:g} ms and leaves at "
                   f"{PAPER.intruder_leave_ms:g} ms (default: on)")
    p.add_argument("--intruder-reading", choices=INTRUDER_READINGS, default="start",
                   help="the intruder takes the first cell its robot is estimated to START "
                   "moving into (default, the paper's 2 s are the intruder's time to get there "
                   "first) or to ARRIVE on, at or after T_a + 2 s")
    p.add_argument("--intruder-stay", metavar="SPEC|FILE", help=STAY_HELP)
    p.add_argument("--informed", action="store_true",
                   help="informed replanning: the replan keeps robots off the cells they "
                   "reported blocked until each block's estimated end")
    p.add_argument("--policy", choices=AUTONOMOUS_POLICIES, default="none",
                   help="replanning policy (default none; at most one replan)")
    p.add_argument("--threshold-ms", metavar="MS", type=float, default=PAPER.threshold_ms,
                   help="fleet slack threshold of the slack policy "
                   f"(default {PAPER.threshold_ms:g})")
    p.add_argument("--solver-time", metavar="measured|zero|MS", type=_solver_time,
                   default="measured",
                   help="virtual time charged for a replan's solver: its CPU time (default), "
                        "nothing, or fixed milliseconds (zero or MS make runs reproducible)")
    add_planning_arguments(p, 60.0)
    p.add_argument("--trace", metavar="FILE.jsonl", help="write the JSON-lines trace here")
    p.add_argument("--json", action="store_true",
                   help='print {"soc_ms", "makespan_ms", "plan_soc", "replans", '
                        '"replan_at_ms", "solver_ms", "collisions"}')
    p.set_defaults(func=_run)
