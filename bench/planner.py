"""Benchmark the 1-robust CBS on the paper's maps against plain CBS measured in the same run.

Instances: random-32-32-20 (scen random-1..5, N = 10, 15, 20, 25), room-32-32-4 (random-1..5,
N = 5, 10, 15) and arena (mapf-IR arena_300agents_1..5, first N = 10, 15, 20, 25 agents).
The baseline is the same CBS with every improvement off (no MDD conflict choice, no heuristic,
no bypass, no target or rectangle reasoning, no conflict-avoidance tie-breaking) under a
per-instance cap.
Times are CPU seconds of this process (the planner is single-threaded) for ``solve_cbs``,
distance tables included, files not. Prints a table per map (seconds)
and one final result line.

``--motion turning`` plans the same instances under the turning model (every robot starting
facing east, the documented default), against plain CBS under turning as the baseline, and
also runs the omni planner in the same process so that the result line shows both.
"""

from __future__ import annotations

import fleetgate.userio.script  # noqa: F401 (first: Ctrl-C while importing is one line)

# isort: split

import statistics
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass
from functools import partial
from pathlib import Path

from fleetgate.userio.exits import CommandParser, run_main
from gateway.planning.cbs import CBSOptions, solve_cbs
from gateway.planning.instance import Instance, load_instance, load_mapf_ir
from gateway.planning.motion import MOTIONS, Motion
from gateway.planning.plan import NoSolution
from gateway.planning.validate import plan_violations

DEFAULT_MAPS = Path(__file__).resolve().parents[2] / "shared" / "maps"
PLAIN = CBSOptions(cardinal=False, heuristic=False, dependency=False, bypass=False, target=False,
                   avoidance=False, rectangle=False)


@dataclass
class CpuDeadline:
    """Expires after ``seconds`` of this process's CPU time (a driver, not the planner).

    CPU time, like the timings printed, so that other jobs on a shared machine do not skew
    the comparison."""

    seconds: float

    def __post_init__(self) -> None:
        self.end = time.process_time() + self.seconds

    def expired(self) -> bool:
        """True once the time is up."""
        return time.process_time() >= self.end


def instances(maps: Path) -> list[tuple[str, Callable[[], Instance]]]:
    """(map label, loader) for every benchmark instance."""
    out: list[tuple[str, Callable[[], Instance]]] = []
    for name, counts in (("random-32-32-20", (10, 15, 20, 25)), ("room-32-32-4", (5, 10, 15))):
        for i in range(1, 6):
            scen = maps / "scen" / f"{name}-random-{i}.scen"
            for n in counts:
                out.append((name, partial(load_instance, maps / f"{name}.map", scen, n)))
    for i in range(1, 6):
        path = maps / "mapf-IR-instances" / f"arena_300agents_{i}.txt"
        for n in (10, 15, 20, 25):
            out.append(("arena", partial(load_mapf_ir, path, n, map_path=maps / "arena.map")))
    return out


def run(inst: Instance, options: CBSOptions, cap: float,
        motion: Motion = "omni") -> tuple[float, int | None]:
    """CPU seconds taken and SOC (None if not solved within ``cap``)."""
    starts = inst.starts if motion == "omni" else inst.turning_starts()
    t0 = time.process_time()
    try:
        sol = solve_cbs(inst.grid, starts, inst.goals, deadline=CpuDeadline(cap),
                        options=options, motion=motion)
    except NoSolution:
        return time.process_time() - t0, None
    dt = time.process_time() - t0
    bad = plan_violations(inst.grid, starts, inst.goals, sol.plan)
    if bad:
        raise SystemExit(f"invalid plan on {inst.name}: {bad[:3]}")
    return dt, sol.plan.soc


def p99(xs: list[float]) -> float:
    """The 99th percentile (nearest rank)."""
    s = sorted(xs)
    return s[min(len(s) - 1, max(0, round(0.99 * len(s)) - 1))]


def main() -> None:
    """Run the benchmark and print the table and the result line."""
    ap = CommandParser(description=__doc__)
    ap.add_argument("--maps-dir", type=Path, default=DEFAULT_MAPS)
    ap.add_argument("--cap", type=float, default=10.0, help="per-instance limit, CPU seconds")
    ap.add_argument("--baseline-cap", type=float, default=2.0,
                    help="per-instance limit of the plain-CBS baseline, CPU seconds")
    ap.add_argument("--no-baseline", action="store_true")
    ap.add_argument("--motion", choices=MOTIONS, default="omni",
                    help="motion model (turning also runs omni for comparison)")
    args = ap.parse_args()
    motion: Motion = args.motion
    rows: dict[str, list[tuple[float, int | None, float, int | None]]] = {}
    omni: list[tuple[float, int | None]] = []
    for label, load in instances(args.maps_dir):
        inst = load()
        dt, soc = run(inst, CBSOptions(), args.cap, motion)
        bdt, bsoc = ((0.0, None) if args.no_baseline
                     else run(inst, PLAIN, args.baseline_cap, motion))
        if soc is not None and bsoc is not None and soc != bsoc:
            raise SystemExit(f"SOC differs on {inst.name} n={inst.num_agents}: {soc} vs {bsoc}")
        rows.setdefault(label, []).append((dt, soc, bdt, bsoc))
        also = ""
        if motion != "omni":
            omni.append(run(inst, CBSOptions(), args.cap))
            also = f"   omni: {omni[-1][0] * 1000:8.1f} ms soc={omni[-1][1]}"
        print(f"  {label:16s} {inst.name:22s} n={inst.num_agents:3d} soc={soc} "
              f"{dt * 1000:8.1f} ms   plain: {bdt * 1000:8.1f} ms soc={bsoc}{also}",
              file=sys.stderr, flush=True)
    print(f"{'map':16s} {'solved':>8s} {'median':>9s} {'p99':>9s} {'max':>9s}   "
          f"{'plain solved':>12s} {'plain median':>12s}")
    all_t: list[float] = []
    ours_sum = plain_sum = 0.0
    for label, rs in rows.items():
        ts = [r[0] for r in rs]
        all_t += ts
        solved = sum(r[1] is not None for r in rs)
        bsolved = sum(r[3] is not None for r in rs)
        bts = [r[2] for r in rs]
        ours_sum += sum(ts)
        plain_sum += sum(bts)
        print(f"{label:16s} {solved:>4d}/{len(rs):<3d} {statistics.median(ts):9.3f} "
              f"{p99(ts):9.3f} {max(ts):9.3f}   {bsolved:>8d}/{len(rs):<3d} "
              f"{statistics.median(bts):12.3f}")
    total = sum(len(rs) for rs in rows.values())
    solved = sum(r[1] is not None for rs in rows.values() for r in rs)
    bsolved = sum(r[3] is not None for rs in rows.values() for r in rs)
    ratio = plain_sum / ours_sum if ours_sum else float("nan")
    name = "cbs" if motion == "omni" else f"cbs {motion}"
    line = (f"RESULT {name} solved {solved}/{total} median "
            f"{statistics.median(all_t) * 1000:.1f} ms max {max(all_t) * 1000:.0f} ms (CPU)")
    if omni:
        ots = [t for t, _ in omni]
        osolved = sum(s is not None for _, s in omni)
        line += (f"; omni solved {osolved}/{total} median {statistics.median(ots) * 1000:.1f} "
                 f"ms max {max(ots) * 1000:.0f} ms")
    if not args.no_baseline:
        plain = "plain CBS" if motion == "omni" else f"plain {motion} CBS"
        line += (f"; {plain} (cap {args.baseline_cap:g} s) solved {bsolved}/{total}; "
                 f"total CPU time plain/ours = {ratio:.1f}x (a lower bound: capped)")
        both = [r for rs in rows.values() for r in rs if r[1] is not None and r[3] is not None]
        if len(both) < total:
            both_ratio = sum(r[2] for r in both) / sum(r[0] for r in both) if both else 0.0
            line += f", {both_ratio:.1f}x on the {len(both)} instances both solved"
    print(line)


if __name__ == "__main__":
    run_main("bench/planner.py", main)
