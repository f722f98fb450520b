"""Lifelong operation: throughput on the LoRR problems, and simulation speed at 1,000 robots.

Part 1 (skipped cleanly if ``../shared/lorr`` is absent): each of the four shared LoRR
problems for ``--ticks`` ticks under its rules (delays from its ``delayConfig``, 1000 ms
planning period at 100 ms a tick, the planner's measured CPU time charged), tasks finished
against the LoRR Start-Kit's reference in ``SOURCES.md`` (one ratio per problem), and the
output replayed by the independent checker (``tracecheck/lorr.py``): collisions
must be 0. ``--delay-seeds K`` runs each problem with K delay seeds (the file's and the next
ones; the reference was measured with the file's) and reports the mean and the smallest ratio,
so a lead is not the luck of one seed.

Part 2: ``--robots`` robots for 600 simulated seconds (one action a second, a plan every
second) on a generated warehouse of about 10,000 free cells (shelf rows, like MovingAI's
warehouse-10-20-10-2-1), in CPU seconds; the goal is 60 s on 2 cores, and LSMART (2026, the
same ADG execution) takes 268 s on 16 cores. Prints one result line.
"""

from __future__ import annotations

import argparse
import dataclasses
import time
from pathlib import Path

from gateway.planning.lorr import read_problem, warehouse_problem
from gateway.planning.movingai import format_map
from sim_clients.lifelong import LifelongConfig, lorr_output, run_lifelong
from tracecheck.lorr import check_output, read_free

REPO = Path(__file__).resolve().parents[1]

SHARED = REPO / ".." / "shared" / "lorr"
REFERENCE = {  # tasks finished in 600 ticks by the Start-Kit's default planner + executor
    "maze": ("maze.domain/maze-example_40.json", 55),
    "room": ("room.domain/room-example_150.json", 107),
    "random": ("random.domain/random-example_400.json", 409),
    "city": ("city.domain/bos-example_600.json", 39),
}


def shared_runs(ticks: int, seeds: int) -> list[str]:
    """One ``name finished/reference=ratio`` entry per shared problem (collisions checked);
    with ``seeds`` > 1, the mean over that many delay seeds (the file's, then the next ones)
    and the smallest ratio."""
    out = []
    for name, (rel, reference) in REFERENCE.items():
        problem = read_problem(SHARED / rel)
        scaled = reference * ticks / 600
        finished = []
        for k in range(seeds):
            delay = dataclasses.replace(problem.delay, seed=problem.delay.seed + k)
            cfg = LifelongConfig(dataclasses.replace(problem, delay=delay), ticks=ticks)
            res = run_lifelong(cfg)
            check_output(lorr_output(cfg, res), read_free(format_map(problem.grid)))
            finished.append(res.finished)
        avg = sum(finished) / seeds
        entry = f"{name} {avg:.0f}/{scaled:.0f}={avg / scaled:.2f}"
        if seeds > 1:
            entry += f" (min {min(finished) / scaled:.2f})"
        out.append(entry)
    return out


def speed_run(robots: int, seconds: int, seed: int) -> tuple[float, int, int]:
    """CPU seconds, tasks finished and free cells of the warehouse run."""
    problem = warehouse_problem(robots, seed)
    cfg = LifelongConfig(problem, ticks=seconds, period=1, tick_ms=1000.0, seed=seed)
    t0 = time.process_time()
    res = run_lifelong(cfg)
    cpu = time.process_time() - t0
    check_output(lorr_output(cfg, res), read_free(format_map(problem.grid)))
    return cpu, res.finished, int(problem.grid.free.sum())


def main() -> None:
    """Run both parts and print one result line."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--ticks", type=int, default=600, help="ticks per LoRR problem")
    ap.add_argument("--robots", type=int, default=1000, help="robots in the speed run")
    ap.add_argument("--seconds", type=int, default=600, help="simulated seconds (speed run)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--delay-seeds", type=int, default=1,
                    help="delay seeds per LoRR problem (mean and min ratio reported)")
    args = ap.parse_args()
    parts = []
    if SHARED.is_dir():
        runs = shared_runs(args.ticks, args.delay_seeds)
        parts.append("tasks vs LoRR reference: " + ", ".join(runs)
                     + f"; collisions 0 over {args.delay_seeds} delay seed(s)")
    else:
        parts.append("LoRR problems skipped (../shared/lorr absent)")
    cpu, finished, cells = speed_run(args.robots, args.seconds, args.seed)
    parts.append(f"speed: {args.robots} robots x {args.seconds} s on {cells} free cells "
                 f"({finished} tasks) in {cpu:.1f} s CPU = {cpu / 60:.2f} x the 60 s goal "
                 f"(LSMART: 268 s on 16 cores)")
    print("lifelong: " + "; ".join(parts))


if __name__ == "__main__":
    main()
