"""``fleetgate lifelong``: a LoRR problem run in virtual time, with the LoRR output JSON."""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys

from fleetgate.userio.files import check_writable, write_text
from gateway.runtime.exits import EXIT_OK, UsageError

SCHEDULER_CHOICES = ("shortest",)
"""``gateway.execution.lifelong.tasks.SCHEDULERS`` (a test checks), named here so --help stays
light."""
MAX_WAIT_TICKS = 600
"""``sim_clients.lifelong.MAX_WAIT_TICKS`` (a test checks), named here for the same reason."""
LANES = 3
"""``sim_clients.lifelong.LANES`` (a test checks), named here for the same reason."""
LANES_ROOMS = 1
"""``sim_clients.lifelong.LANES_ROOMS`` (a test checks), named here for the same reason."""
DOORS = 20
"""``sim_clients.lifelong.DOORS`` (a test checks), named here for the same reason."""
CORRIDOR_LANES = 20
"""``sim_clients.lifelong.CORRIDOR_LANES`` (a test checks), named here for the same reason."""
LNS_ROUNDS = 200
"""``sim_clients.lifelong.LNS_ROUNDS`` (a test checks), named here for the same reason."""


def _planner_time(text: str) -> str | float:
    if text in ("measured", "zero"):
        return text
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"planner time must be 'measured', 'zero' or ms, got {text!r}") from None
    if not 0 <= value < float("inf"):
        raise argparse.ArgumentTypeError(f"planner time must be finite ms >= 0, got {text!r}")
    return value


def _run(args: argparse.Namespace) -> int:
    from rich.console import Console
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn

    from gateway.execution.lifelong.tasks import wait_percentiles
    from gateway.planning.lorr import LorrFormatError, read_problem
    from gateway.planning.pibt import compact_needed, exact_fits
    from sim_clients.lifelong import (
        PLANNER_BUDGET,
        LifelongConfig,
        lorr_output,
        mean,
        run_lifelong,
        tasks_per_tick,
    )

    for name in ("ticks", "period"):
        if getattr(args, name) <= 0:
            raise UsageError(f"--{name} must be positive, got {getattr(args, name)}")
    for name in ("window", "reassign", "max_wait", "lanes", "doors", "lns"):
        if (getattr(args, name) or 0) < 0:
            raise UsageError(f"--{name.replace('_', '-')} must be >= 0, "
                             f"got {getattr(args, name)}")
    try:
        problem = read_problem(args.problem)
    except LorrFormatError as exc:
        raise UsageError(str(exc)) from None
    if args.delay_seed is not None:
        problem = dataclasses.replace(problem, delay=dataclasses.replace(problem.delay,
                                                                         seed=args.delay_seed))
    grid, robots = problem.grid, problem.team_size
    fits = {"lanes": ("tables of moves", not compact_needed(grid, robots, PLANNER_BUDGET)),
            "doors": ("exact tables", exact_fits(grid, robots, PLANNER_BUDGET))}
    for name, (tables, fit) in fits.items():
        if getattr(args, name) and (args.motion != "turning" or not fit):
            raise UsageError(f"--{name} needs the turning motion and a map whose {tables} "
                             f"fit 2 GB ({problem.name}: {grid.width}x{grid.height}, "
                             f"{robots} robots)"
                             if args.motion == "turning" else f"--{name} needs --motion turning")
    if args.output:
        check_writable(args.output)  # before the run, not after it
    cfg = LifelongConfig(problem=problem, ticks=args.ticks, turning=args.motion == "turning",
                         period=args.period, window=args.window,
                         planner_time=args.planner_time, scheduler=args.scheduler,
                         max_wait=args.max_wait or None,
                         reassign=args.reassign, lanes=args.lanes, doors=args.doors,
                         lns=args.lns, seed=args.seed)
    with Progress(TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(),
                  TextColumn("ticks, {task.fields[done]} tasks"),
                  disable=not args.progress, transient=True,
                  console=Console(stderr=True)) as bar:
        task = bar.add_task(problem.name, total=args.ticks, done=0)
        result = run_lifelong(cfg, lambda t, done: bar.update(task, completed=t, done=done))
    if args.output:
        write_text(args.output, json.dumps(lorr_output(cfg, result)))
    times = result.planner_times
    wait = wait_percentiles(result.waits)
    print(f"{problem.name}: {problem.team_size} robots, {args.ticks} ticks: "
          f"{result.finished} tasks finished, {tasks_per_tick(result):.3f} per tick; "
          f"planner {1000 * mean(times):.1f} ms per call (max {1000 * max(times, default=0):.1f}, "
          f"{len(times)} calls); assignment wait p50 {wait['p50']:g} p90 {wait['p90']:g} "
          f"p99 {wait['p99']:g} max {wait['max']:g} ticks")
    return EXIT_OK


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    """Add ``fleetgate lifelong``."""
    p = sub.add_parser(
        "lifelong", help="a lifelong (LoRR) problem in virtual time",
        description="Run a League of Robot Runners problem in virtual time: tasks, delays, "
                    "periodic windowed planning appended to a live ADG; writes the LoRR "
                    "output JSON. Exit codes: 0 success, 2 bad input.")
    p.add_argument("--problem", required=True, metavar="PROBLEM.json",
                   help="LoRR problem file (its map, agent and task files beside it)")
    p.add_argument("--ticks", type=int, default=600, help="execution ticks (default 600)")
    p.add_argument("--output", metavar="OUT.json", help="write the LoRR output JSON here")
    p.add_argument("--motion", choices=("turning", "omni"), default="turning",
                   help="motion model (default turning, LoRR's MAPF_T)")
    p.add_argument("--period", type=int, default=10,
                   help="ticks between planning calls (default 10: 1000 ms at 100 ms a tick)")
    p.add_argument("--window", type=int, default=0,
                   help="timesteps planned per call (default 0: enough for a period)")
    p.add_argument("--planner-time", type=_planner_time, default="measured",
                   metavar="measured|zero|MS",
                   help="planner time charged per call (default: measured CPU time)")
    p.add_argument("--scheduler", choices=SCHEDULER_CHOICES, default="shortest",
                   help="task assignment (default shortest: cheapest robot-task pairs by "
                        "distance to the first errand plus the task's length)")
    p.add_argument("--max-wait", type=int, default=MAX_WAIT_TICKS, metavar="TICKS",
                   help="fairness bound: a task that waited this many ticks for a robot goes "
                        "before the tasks of its priority that did not (default "
                        f"{MAX_WAIT_TICKS}; 0: no bound)")
    p.add_argument("--reassign", type=int, default=1, metavar="CALLS",
                   help="planning calls between reassignments of tasks not started yet "
                        "(default 1: every call; 0: never)")
    p.add_argument("--lanes", type=int, default=None, metavar="PENALTY",
                   help="guide the turning planner by crisscross lanes (even rows east, odd "
                        "rows west, even columns south, odd columns north): a move against its "
                        "lane costs PENALTY half-moves more; where the exact tables do not fit "
                        "the planner's 2 GB, the one-cell corridors' lanes instead, taking "
                        "turns; 0: no lanes (default: "
                        f"{LANES} where the exact tables fit, {LANES_ROOMS} there on a map with "
                        f"one-way doors, else {CORRIDOR_LANES} on a map of one-cell corridors "
                        "if a table of moves per robot fits, else none)")
    p.add_argument("--doors", type=int, default=None, metavar="PENALTY",
                   help="make the one-cell doors between two rooms that have two or more "
                        "one way, taking turns: a move against a door costs PENALTY half-moves "
                        f"more; 0: no one-way doors (default: {DOORS} where the exact tables "
                        "fit the planner's 2 GB, else none)")
    p.add_argument("--lns", type=int, default=None, metavar="ROUNDS",
                   help="refine each planned window by ROUNDS rounds of large neighbourhood "
                        "search (groups of neighbouring robots replanned, kept if cheaper; "
                        "turning motion with exact tables only); 0: none (default: half a "
                        f"round per robot up to {LNS_ROUNDS} when an action lasts more than "
                        "one tick and the map has no one-way doors, else none)")
    p.add_argument("--seed", type=int, default=0, help="planner tie-break seed (default 0)")
    p.add_argument("--delay-seed", type=int, default=None, metavar="SEED",
                   help="seed of the delay model (default: the problem's delayConfig seed)")
    p.add_argument("--progress", action=argparse.BooleanOptionalAction,
                   default=sys.stderr.isatty(), help="progress bar (default: on a terminal)")
    p.set_defaults(func=_run)
