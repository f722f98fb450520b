"""In-process owner benchmark: the owner task's CPU per action for the same work in every run.

One gateway and its simulated robots (:mod:`sim_clients.fleet` on in-memory links) run in one
process on virtual time: every robot event reaches the owner at the same virtual instant in
every run, so each run hands the owner the same sequence of wake-ups, reports, ticks and
journal commits however loaded the machine is (a real-time run batches more events per
wake-up, and per commit, when the machine is busy). The CPU time that work takes still moves
with the load (shared caches and cores): read the ratio against a baseline of the same run.
Only the owner task's thread CPU is counted (the robots and the connections' decoding run in
tasks of their own). The journal and the trace are on, dispatch lookahead 1, as in
``bench/load.py --lookahead 1 --journal``.

Each run is a child process. With ``--against DIR`` the gateway of DIR's checkout runs the
same workload (this script with DIR first on the path), interleaved with this one, and
``owner_cpu_per_action_ratio`` is this / that (median over ``--pairs``). Every run also times
the bare executor on the same plan (``bench/sim_speed.py``'s loop) in the same process:
``owner_over_bare`` is the owner's CPU per action over it, a ratio that machine speed cancels
out of. Prints one result line (``--json``: one JSON line).
"""

from __future__ import annotations

import fleetgate.userio.script  # noqa: F401 (first: Ctrl-C while importing is one line)

# isort: split

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from fleetgate.userio.exits import CommandParser, run_main
from gateway.planning.instance import Instance
from gateway.planning.random_plans import open_grid
from gateway.runtime.exits import UsageError
from gateway.server.clock import VirtualClock, run_virtual
from gateway.server.config import GatewayConfig
from gateway.server.gateway import Gateway
from gateway.server.planner import Problem
from sim_clients.fleet import SimFleet, fleet_for, run_in_process
from tracecheck import check_trace, read_trace

sys.path.append(str(Path(__file__).resolve().parent.parent))  # after DIR's (--against)

from bench.load import workload
from bench.sim_speed import bare_executor


async def _run(robots: int, steps: int, seed: int, jitter: float, tmp: Path
               ) -> dict[str, Any]:
    """One execution of the workload on virtual time; the owner's measurements."""
    size, plan = workload(robots, steps, seed)
    grid = open_grid(size, size)
    inst = Instance(grid, tuple(p[0] for p in plan.paths), tuple(p[-1] for p in plan.paths),
                    "owner")
    trace = tmp / "trace.jsonl"
    config = GatewayConfig(port=0, map=None, policy="none", log_level="WARNING",
                           dispatch_lookahead=1, journal=tmp / "journal.sqlite", trace=trace,
                           workers=0)  # virtual time: the owner alone, in this process
    async with Gateway(config, clock=VirtualClock()) as gw:
        gw.engine.meter_cpu = True
        fleet: SimFleet = fleet_for(gw, robots, gw.connect, seed=seed, intruder=False)
        fleet.duration_jitter = jitter
        owner0 = [0.0]

        async def before_start() -> None:  # the execution only, not the connections
            owner0[0] = gw.engine.cpu_s

        try:
            await run_in_process(gw, Problem(inst, "owner", plan), fleet, before_start)
        finally:
            await fleet.stop()
        owner_s = gw.engine.cpu_s - owner0[0]
        journal = gw.engine.journal
        commits = journal.commits if journal is not None else 0
    total = sum(len(p) - 1 for p in plan.paths)
    checked = check_trace(read_trace(trace))
    t0 = time.thread_time()
    bare_executor(plan)
    bare_s = time.thread_time() - t0
    return {"actions": total, "received": len(fleet.stats.received),
            "duplicated": fleet.stats.duplicates, "errors": len(fleet.stats.errors),
            "trace_errors": len(checked.errors), "collisions": len(checked.collisions),
            "owner_cpu_s": owner_s, "bare_cpu_s": bare_s, "commits": commits}


def serve_main(args: argparse.Namespace) -> None:
    """``--child``: one run in this process; print its JSON line."""
    with tempfile.TemporaryDirectory() as tmp:
        print(json.dumps(run_virtual(_run(args.robots, args.steps, args.seed, args.jitter,
                                          Path(tmp)))), flush=True)


def run_child(args: argparse.Namespace, tree: Path | None) -> dict[str, Any]:
    """One run in a child process (with ``tree``'s packages first on the path)."""
    cmd = [sys.executable, __file__, "--child", "--robots", str(args.robots), "--steps",
           str(args.steps), "--seed", str(args.seed), "--jitter", str(args.jitter)]
    # here, not at the top: a child runs with DIR's packages, which may predate this module
    from fleetgate.userio import children

    env = {**os.environ, "PYTHONPATH": str(tree)} if tree else None
    with children.running(cmd, env=env, stdout=subprocess.PIPE, text=True) as proc:
        out, _ = proc.communicate()
    if proc.returncode != 0 or not out.strip():
        raise UsageError(f"the run with {tree or 'this checkout'} failed (its error is above)")
    run: dict[str, Any] = json.loads(out.strip().splitlines()[-1])
    n = run["actions"]
    run["owner_cpu_ms_per_action"] = round(1000.0 * run["owner_cpu_s"] / n, 4)
    run["owner_over_bare"] = round(run["owner_cpu_s"] / run["bare_cpu_s"], 3)
    run["commits_per_action"] = round(run["commits"] / n, 3)
    run["lost"] = n - run["received"]
    return run


def main() -> None:
    """Parse arguments and run."""
    p = CommandParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--robots", type=int, default=1000)
    p.add_argument("--steps", type=int, default=20, help="plan steps per robot")
    p.add_argument("--seed", type=int, default=1)
    p.add_argument("--jitter", type=float, default=0.2,
                   help="actions last 1000 ms x U(1-J, 1+J) (default 0.2)")
    p.add_argument("--pairs", type=int, default=1, help="runs of each version (default 1)")
    p.add_argument("--against", type=Path, metavar="DIR",
                   help="also run the gateway of the checkout DIR, interleaved")
    p.add_argument("--json", action="store_true", help="print the result as one JSON line")
    p.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    args = p.parse_args()
    if args.robots < 1 or args.steps < 1 or args.pairs < 1 or not 0.0 <= args.jitter < 1.0:
        raise UsageError("--robots, --steps and --pairs must be >= 1, --jitter in [0, 1)")
    if args.against is not None and not (args.against / "gateway").is_dir():
        raise UsageError(f"--against {args.against}: not a fleetgate checkout")
    if args.child:
        serve_main(args)
        return
    these: list[dict[str, Any]] = []
    those: list[dict[str, Any]] = []
    for _ in range(args.pairs):
        these.append(run_child(args, None))
        if args.against is not None:
            those.append(run_child(args, args.against.resolve()))
    out: dict[str, Any] = {
        "robots": args.robots, "steps": args.steps, "pairs": args.pairs,
        "owner_cpu_ms_per_action": [r["owner_cpu_ms_per_action"] for r in these],
        "owner_over_bare": statistics.median(r["owner_over_bare"] for r in these),
        "commits_per_action": these[0]["commits_per_action"],
        **{k: max(r[k] for r in these + those)
           for k in ("lost", "duplicated", "errors", "trace_errors", "collisions")},
        "load_1min": round(os.getloadavg()[0], 1)}
    if those:
        out["against"] = str(args.against)
        out["against_owner_cpu_ms_per_action"] = [r["owner_cpu_ms_per_action"] for r in those]
        out["against_owner_over_bare"] = statistics.median(r["owner_over_bare"] for r in those)
        out["against_commits_per_action"] = those[0]["commits_per_action"]
        out["owner_cpu_per_action_ratio"] = round(statistics.median(
            a["owner_cpu_s"] / b["owner_cpu_s"] for a, b in zip(these, those, strict=True)), 3)
    if args.json:
        print(json.dumps(out))
        return
    ratio = (f"; against {args.against}: {out['against_owner_cpu_ms_per_action']} ms, "
             f"ratio {out['owner_cpu_per_action_ratio']}") if those else ""
    print(f"RESULT owner {args.robots} robots x {args.steps} steps (virtual time, journal on): "
          f"{out['owner_cpu_ms_per_action']} ms of owner CPU per action, "
          f"{out['owner_over_bare']}x the bare executor{ratio}; lost {out['lost']}, "
          f"duplicated {out['duplicated']}, trace errors {out['trace_errors']}")


if __name__ == "__main__":
    run_main("bench/owner.py", main)
