"""Benchmark what an operator's snapshot costs the gateway in lifelong mode.

A lifelong snapshot (:func:`gateway.server.views.shift_fields`: the map, every robot's
committed path from where it stands, its task's errands, who waits for whom) is built,
validated and encoded for a 500-robot warehouse shift a few planning windows in (robots hold
their dispatched actions); the baseline is the one-shot snapshot of a 500-robot plan (random
1-robust walks of 28 steps on a 64 x 64 map, the monitor benchmark's plan) that is running,
measured in the same run. The GUI asks for one every 250 ms per 60 robots, at most every 2 s,
so at 500 robots the lifelong snapshot costs ``lifelong_ms / 2000`` of a core per operator.
Prints one line: the ratio of median costs, both medians, the lifelong snapshot's size, and
(for information) the median cost of one action event (the feed sends three per action, so
about 1,500 a second at 500 robots).

    .venv/bin/python bench/feed.py [--robots 500] [--windows 5] [--repeat 15] [--json]
"""

from __future__ import annotations

import fleetgate.userio.script  # noqa: F401 (first: Ctrl-C while importing is one line)

# isort: split

import json
import random
import statistics
import time
from typing import Any

from fleetgate.userio.exits import CommandParser, run_main
from gateway.execution.commands import Dispatch
from gateway.execution.lifelong.errands import TaskDistances
from gateway.execution.lifelong.executor import LifelongExecutor, PlanRequest, WindowPlanner
from gateway.execution.lifelong.tasks import TaskPool
from gateway.execution.oneshot.executor import Executor
from gateway.planning.instance import Instance
from gateway.planning.lorr import warehouse_problem
from gateway.planning.plan import Plan
from gateway.planning.random_plans import open_grid, random_walks
from gateway.server.planner import Problem
from gateway.server.views import FleetView, ShiftView, snapshot_fields
from protocol import Event, Pose, Snapshot, encode
from protocol.gateway_session import GatewaySession


def _view(robots: dict[int, GatewaySession], problem: Problem | None = None,
          executor: Executor | None = None, shift: ShiftView | None = None) -> FleetView:
    return FleetView(t_ms=1000.0, max_replans=1, status="running", threshold_ms=2000.0,
                     policy="slack", speed=1.0, slack_series=[], intruders=[], replan_marks=[],
                     problem=problem, executor=executor, robots=robots, shift=shift)


def _hold(sessions: dict[int, GatewaySession], commands: list[Any]) -> None:
    """The sessions hold what was dispatched (as the engine's would)."""
    for c in commands:
        if isinstance(c, Dispatch):
            sessions.setdefault(c.robot, GatewaySession(c.robot)).dispatch({
                "action_id": f"{c.plan}.{c.robot}.{c.action}", "sequence": c.action,
                "src": Pose(cell=c.src), "dst": Pose(cell=c.dst),
                "duration_ms": c.duration_ms})


def lifelong_view(robots: int, windows: int, seed: int) -> FleetView:
    """A shift ``windows`` planning calls in, its robots holding their dispatched actions."""
    prob = warehouse_problem(robots, seed)
    grid = prob.grid
    ex = LifelongExecutor(grid, prob.starts, [0] * robots, TaskPool(prob.tasks, robots),
                          distances=TaskDistances(grid), lookahead=1)
    planner = WindowPlanner(grid, robots, True, seed)
    sessions: dict[int, GatewaySession] = {}
    ex.start(0.0)
    for k in range(windows):
        out = ex.drain()
        _hold(sessions, out)
        req = next(c for c in out if isinstance(c, PlanRequest))
        ex.adopt(planner(req), 10.0 + 1000.0 * k)
        ex.tick(1000.0 * (k + 1))
    _hold(sessions, ex.drain())
    return _view(sessions, shift=ShiftView(prob.name or "warehouse", ex, 1000.0))


def oneshot_view(robots: int, seed: int) -> FleetView:
    """The baseline: a running 500-robot one-shot plan."""
    grid = open_grid(64, 64)
    plan = Plan.of(random_walks(grid, robots, 28, random.Random(seed)))
    ex = Executor(plan, lookahead=1)
    ex.start(0.0)
    sessions: dict[int, GatewaySession] = {}
    _hold(sessions, ex.drain())
    problem = Problem(Instance(grid, tuple(p[0] for p in plan.paths),
                               tuple(p[-1] for p in plan.paths), "open"), "open", plan)
    return _view(sessions, problem=problem, executor=ex)


def cost_ms(view: FleetView, repeat: int) -> tuple[float, int]:
    """Median ms to build, validate and encode the snapshot of ``view``; its size in bytes."""
    def build() -> str:
        return encode(Snapshot(msg_id="s", seq=0, **snapshot_fields(view)))

    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        text = build()
        times.append((time.perf_counter() - t0) * 1000.0)
    return statistics.median(times), len(text.encode())


def event_us(repeat: int) -> float:
    """Median microseconds to build and encode one action event (what the feed sends an
    operator per dispatch, start and finish: three per action)."""
    times = []
    for k in range(repeat * 100):
        t0 = time.perf_counter()
        encode(Event(msg_id="e", seq=k, event="finish", t_ms=float(k), plan=0, robot=k % 500,
                     action=k))
        times.append((time.perf_counter() - t0) * 1e6)
    return statistics.median(times)


def main() -> int:
    """Run the benchmark and print its result line."""
    ap = CommandParser(description=__doc__.splitlines()[0])
    ap.add_argument("--robots", type=int, default=500)
    ap.add_argument("--windows", type=int, default=5)
    ap.add_argument("--repeat", type=int, default=15)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--json", action="store_true", help="print the result as one JSON line")
    args = ap.parse_args()
    life_ms, size = cost_ms(lifelong_view(args.robots, args.windows, args.seed), args.repeat)
    base_ms, _ = cost_ms(oneshot_view(args.robots, args.seed), args.repeat)
    result = {"robots": args.robots, "snapshot_ratio": round(life_ms / base_ms, 3),
              "lifelong_ms": round(life_ms, 2), "oneshot_ms": round(base_ms, 2),
              "lifelong_bytes": size, "event_us": round(event_us(args.repeat), 1)}
    if args.json:
        print(json.dumps(result))
    else:
        print(f"lifelong snapshot {life_ms:.2f} ms vs one-shot {base_ms:.2f} ms at "
              f"{args.robots} robots: ratio {result['snapshot_ratio']} ({size} bytes); "
              f"an action event {result['event_us']} us")
    return 0


if __name__ == "__main__":
    run_main("bench/feed.py", main)
