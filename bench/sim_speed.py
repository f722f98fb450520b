"""Speed of the discrete-event simulator (``sim_clients.des``): one run with 15 robots on lab.

Plans ``lab`` / ``lab-random-1`` with the first 15 agents once, then times ``--runs``
simulations with the intruder and the slack policy (solver time charged as zero; seeds
0..runs-1) and, as the baseline measured in the same run, the bare executor on the same plan
driven by a minimal loop (every dispatched action finishes 1000 ms later; no world, robots,
intruder or monitor ticks). Prints one result line.
"""

from __future__ import annotations

import fleetgate.userio.script  # noqa: F401 (first: Ctrl-C while importing is one line)

# isort: split

import heapq
import statistics
import time
from collections.abc import Callable

from fleetgate.userio.exits import CommandParser, run_main
from gateway.execution.commands import Dispatch
from gateway.execution.oneshot.executor import Executor
from gateway.planning.instance import load_instance
from gateway.planning.plan import Plan
from gateway.planning.solver import solve
from gateway.runtime.deadline import WallDeadline
from gateway.runtime.mapstore import resolve
from sim_clients.des import SimConfig, run_simulation


def bare_executor(plan: Plan) -> None:
    """Execute ``plan`` with the executor alone: the cost a driver cannot go below."""
    ex = Executor(plan)
    ex.start(0.0)
    pending: list[tuple[float, int, int, int]] = []
    now = 0.0
    while not ex.done:
        for c in ex.drain():
            if isinstance(c, Dispatch):
                ex.started(c.robot, c.plan, c.action, now)
                heapq.heappush(pending, (now + c.duration_ms, c.robot, c.plan, c.action))
        if ex.done:
            break
        now, robot, plan_id, action = heapq.heappop(pending)
        ex.finished(robot, plan_id, action, now)


def timed(fn: Callable[[], object], reps: int) -> list[float]:
    """Wall seconds of ``reps`` calls of ``fn``."""
    out = []
    for _ in range(reps):
        t0 = time.perf_counter()
        fn()
        out.append(time.perf_counter() - t0)
    return out


def main() -> None:
    """Run the benchmark and print the result line."""
    ap = CommandParser(description=__doc__)
    ap.add_argument("--agents", type=int, default=15)
    ap.add_argument("--runs", type=int, default=50)
    args = ap.parse_args()
    inst = load_instance(resolve("lab", "map"), resolve("lab-random-1", "scen"), args.agents)
    plan = solve(inst.grid, inst.starts, inst.goals, deadline=WallDeadline(60.0)).plan
    configs = [SimConfig(inst.grid, plan, seed=s, intruder=True, policy="slack",
                         solver_time="zero") for s in range(args.runs)]
    run_simulation(configs[0])  # warm-up
    sims = []
    virtual = []
    for config in configs:
        t0 = time.perf_counter()
        result = run_simulation(config)
        sims.append(time.perf_counter() - t0)
        virtual.append(result.end_ms)
    base = timed(lambda: bare_executor(plan), args.runs)
    sim_ms, base_ms = statistics.median(sims) * 1000, statistics.median(base) * 1000
    print(f"RESULT des lab {args.agents} robots intruder+slack: median {sim_ms:.1f} ms/run "
          f"(max {max(sims) * 1000:.1f}), {statistics.median(virtual) / sim_ms:.0f}x faster than "
          f"real time; bare executor {base_ms:.1f} ms/run; des/bare = {sim_ms / base_ms:.2f}x")


if __name__ == "__main__":
    run_main("bench/sim_speed.py", main)
