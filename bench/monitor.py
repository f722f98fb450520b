"""Benchmark the incremental slack monitor against a full Algorithm 1 recomputation.

A 500-robot 1-robust plan is executed in a discrete-event loop with random delays (moves take
1000 ms, but 3 % of dispatched actions wait 0.5-4 s for their cell before starting and 3 % of
moves are slow, 1-2.5 s; the executor is ticked every 100 ms). Each finish event's cost
(``Executor.finished``: monitor update plus dispatching) is timed; at evenly spread finish
events the full recomputation (``monitor.algorithm1`` over the whole ADG, the baseline) is
timed on the same state and checked equal to the incremental one.

No planner is needed: the plan is random 1-robust walks
(:func:`gateway.planning.random_plans.random_walks`, checked with the plan validator). Prints
one line: the ratio of medians and the median microseconds per finish event (and, for
information, the median cost of a 100 ms tick, which re-clamps the overdue frontier actions
and propagates to their descendants).

    .venv/bin/python bench/monitor.py [--robots 500] [--size 64] [--steps 28] [--seed 1]
"""

from __future__ import annotations

import fleetgate.userio.script  # noqa: F401 (first: Ctrl-C while importing is one line)

# isort: split

import heapq
import random
import statistics
import sys
import time

from fleetgate.userio.exits import CommandParser, run_main
from gateway.execution.commands import Dispatch
from gateway.execution.oneshot.executor import MONITOR_PERIOD_MS, Executor
from gateway.execution.oneshot.monitor import algorithm1
from gateway.planning.plan import Plan
from gateway.planning.random_plans import open_grid, random_walks
from gateway.planning.validate import plan_violations


def main() -> int:
    """Run the benchmark and print its result line."""
    ap = CommandParser(description=__doc__.splitlines()[0])
    ap.add_argument("--robots", type=int, default=500)
    ap.add_argument("--size", type=int, default=64)
    ap.add_argument("--steps", type=int, default=28,
                    help="timesteps of every walk (28: about 14,000 actions for 500 robots)")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--samples", type=int, default=25, help="full recomputations to time")
    args = ap.parse_args()
    rng = random.Random(args.seed)
    grid = open_grid(args.size, args.size)
    paths = random_walks(grid, args.robots, args.steps, rng)
    violations = plan_violations(grid, [p[0] for p in paths], [p[-1] for p in paths], paths)
    if violations:
        print(f"generated plan is invalid: {violations[0]}", file=sys.stderr)
        return 1
    plan = Plan.of(paths)
    built = time.perf_counter()
    ex = Executor(plan)
    build_s = time.perf_counter() - built
    adg = ex.adg
    nv = adg.n_vertices
    started: list[float | None] = [None] * nv
    finished: list[float | None] = [None] * nv
    total_finishes = nv
    sample_every = max(1, total_finishes // args.samples)

    queue: list[tuple[float, int, str, int]] = []
    seq = 0

    def at(t: float, kind: str, v: int) -> None:
        nonlocal seq
        seq += 1
        heapq.heappush(queue, (t, seq, kind, v))

    ex.start(0.0)
    at(MONITOR_PERIOD_MS, "tick", -1)
    incremental: list[float] = []
    full: list[float] = []
    ticks: list[float] = []
    finishes = 0
    while not ex.done:
        for cmd in ex.drain():
            if isinstance(cmd, Dispatch):
                v = adg.vertex(cmd.robot, cmd.action)
                delay = float(rng.randint(500, 4000)) if rng.random() < 0.03 else 0.0
                at(ex.now_ms + delay, "start", v)
        if ex.done:
            break
        t, _, kind, v = heapq.heappop(queue)
        if kind == "tick":
            t0 = time.perf_counter()
            ex.tick(t)
            ticks.append(time.perf_counter() - t0)
            at(t + MONITOR_PERIOD_MS, "tick", -1)
        elif kind == "start":
            ex.started(adg.robot_of[v], 0, adg.step_of[v], t)
            started[v] = t
            at(t + (rng.randint(1000, 2500) if rng.random() < 0.03 else 1000), "finish", v)
        else:
            t0 = time.perf_counter()
            ex.finished(adg.robot_of[v], 0, adg.step_of[v], t)
            incremental.append(time.perf_counter() - t0)
            finished[v] = t
            finishes += 1
            if finishes % sample_every == 0:
                t0 = time.perf_counter()
                oracle = algorithm1(adg, now_ms=ex.monitor.now_ms, action_ms=ex.monitor.tx,
                                    release_ms=[0.0] * adg.n_robots, started_ms=started,
                                    finished_ms=finished)
                full.append(time.perf_counter() - t0)
                mine = ex.monitor.snapshot()
                if (mine.ts, mine.tc, mine.delta) != (oracle.ts, oracle.tc, oracle.delta):
                    print(f"incremental monitor differs from Algorithm 1 at t={t}",
                          file=sys.stderr)
                    return 1
    inc_us = statistics.median(incremental) * 1e6
    full_us = statistics.median(full) * 1e6
    edges = len(adg.t2_succ)
    print(f"monitor: {args.robots} robots, {nv} actions, {edges} type-2 edges "
          f"(ADG built in {build_s:.2f} s); finish event median {inc_us:.1f} us incremental vs "
          f"{full_us / 1000:.1f} ms full Algorithm 1 recompute: ratio {full_us / inc_us:.0f}x "
          f"over {len(incremental)} events; tick (re-clamp and propagate) median "
          f"{statistics.median(ticks) * 1e6:.0f} us (SOC {ex.soc_ms / 1000:.0f} s, "
          f"plan SOC {plan.soc} steps)")
    return 0


if __name__ == "__main__":
    run_main("bench/monitor.py", main)
