"""How much of the clairvoyant's saving could a policy that does not know the intruder's stay
capture, at best, with one replan? (:mod:`experiments.stay_bound`; not a timed test.)

Reads a campaign folder of ``fleetgate experiment`` (its instances, settings and
experiments; the campaign must have a varying ``--intruder-stay``), simulates a seeded
sample of its experiments over a grid of equally likely stays (no replan; a forced informed
replan every ``--step`` s from ``T_a`` for each assumed stay; the clairvoyant's), and prints one
line: the best pooled capture of the clairvoyant's expected saving (the baseline, measured in
the same run) with at most ``--budget`` of the experiments worse than not replanning, for
replans from the block's first report (what an online policy can know), from one second
after it, and from ``T_a`` (knowing the cell as early as the clairvoyant), and the never-losing
choice's capture. ``--tables FILE`` also writes each experiment's savings table (JSON lines).

``--switches 1|2`` also bounds policies that decide more than once
(:mod:`experiments.stay_paths`): up to that many switches while the block lasts (the second
to a longer assumed stay, every ``--second-step`` s), each path settled when the block ends by
the better of keeping its plan and replanning back; the line then adds the best such
policy's capture, with 1 switch and with 2.
"""

from __future__ import annotations

import fleetgate.userio.script  # noqa: F401 (first: Ctrl-C while importing is one line)

# isort: split

import json
import time
from pathlib import Path

import numpy as np

from experiments.campaign import InstanceRecord, SimSettings, load_grid, variant_config
from experiments.stay_bound import Bound, GainTable, best_capture, gain_table, stay_grid
from experiments.stay_paths import PathTable, best_path_capture, path_table
from fleetgate.userio.exits import CommandParser, run_main
from fleetgate.userio.files import write_text
from gateway.planning.seeds import derive_seed
from gateway.runtime.exits import UsageError
from gateway.runtime.mapstore import MapNotFound, resolve
from sim_clients.stays import parse_stay


def _line(label: str, got: Bound) -> str:
    median = "n/a" if got.median is None else f"{100 * got.median:.0f}%"
    return (f"{label}: capture {100 * got.capture:.1f}% (worse {100 * got.worse:.2f}%, median "
            f"{median}, never-losing {100 * got.never_losing:.1f}%)")


def _paths_line(paths: list[PathTable], budget: float, switches: int) -> str:
    capture, worse, median = best_path_capture(paths, budget, switches)
    safe = best_path_capture(paths, 0.0, switches)[0]
    shown = "n/a" if median is None else f"{100 * median:.0f}%"
    return (f"up to {switches} switch(es), replanning back: capture {100 * capture:.1f}% "
            f"(worse {100 * worse:.2f}%, median {shown}, never-losing {100 * safe:.1f}%)")


def main() -> None:
    """Simulate the sample and print the result line."""
    p = CommandParser(description=__doc__)
    p.add_argument("folder", type=Path, help="a fleetgate experiment --out folder")
    p.add_argument("--points", type=int, default=12, help="stays in the grid (default 12)")
    p.add_argument("--sample", type=int, default=40, help="experiments (default 40)")
    p.add_argument("--budget", type=float, default=0.01,
                   help="largest worse-than-none share (default 0.01)")
    p.add_argument("--assumed", default="0.25,0.5,0.75,0.9,0.99",
                   help="the assumed stays, as quantile levels of the distribution")
    p.add_argument("--maps-dir", default=None)
    p.add_argument("--tables", type=Path, default=None, help="write the savings tables here")
    p.add_argument("--switches", type=int, default=0,
                   help="also bound policies with up to this many switches (0, 1 or 2)")
    p.add_argument("--step", type=float, default=1.0,
                   help="seconds between the replan (first switch) times (default 1)")
    p.add_argument("--second-step", type=float, default=2.0,
                   help="seconds between the second switch's times (default 2)")
    args = p.parse_args()
    try:
        settings = json.loads((args.folder / "campaign.json").read_text())
        keys = sorted({(r[0], int(r[1]), int(r[2]), int(r[3])) for r in (
            line.split(",") for line in
            (args.folder / "results.csv").read_text().splitlines()[1:]) if r[4] == "intruder"})
    except (OSError, ValueError, IndexError) as exc:
        raise UsageError(f"{args.folder}: not a campaign folder ({exc})") from None
    if not settings.get("intruder_stay"):
        raise UsageError(f"{args.folder}: the campaign has the paper's fixed stay")
    if not (args.points >= 2 and args.sample >= 1 and 0 <= args.budget < 1
            and args.switches in (0, 1, 2) and args.step > 0 and args.second_step > 0):
        raise UsageError("need --points >= 2, --sample >= 1, 0 <= --budget < 1, --switches "
                         "0, 1 or 2 and --step, --second-step > 0")
    spec = parse_stay(settings["intruder_stay"])
    levels = [float(x) for x in args.assumed.split(",")]
    grid = stay_grid(spec, args.points)
    assumed = stay_grid(spec, 100_000)  # fine quantiles, read at the levels below
    assumed_s = [assumed[min(len(assumed) - 1, int(q * len(assumed)))] for q in levels]
    sim = SimSettings(solver_time="zero", intruder_appear_ms=settings["intruder_appear_ms"],
                      intruder_reading=settings["intruder_reading"])
    rng = np.random.default_rng(derive_seed(int(settings["seed"]), "stay-bound"))
    picked = sorted(rng.permutation(len(keys))[:args.sample].tolist())
    tables: list[GainTable] = []
    paths: list[PathTable] = []
    began = time.process_time()
    for j in picked:
        m, n, i, seed = keys[j]
        try:
            rec = InstanceRecord.from_json(json.loads(
                (args.folder / "instances" / f"{m}-{n}-{i:03d}.json").read_text()))
            path = resolve(m, "map", args.maps_dir)
        except (OSError, ValueError, KeyError, MapNotFound) as exc:
            raise UsageError(f"{args.folder}: {m}-{n}-{i}: {exc}") from None
        config = variant_config(load_grid(str(path)), rec.plan, seed, "intruder", sim)
        tables.append(gain_table(config, keys[j], grid, assumed_s, 1000.0 * args.step))
        if args.switches:
            paths.append(path_table(config, keys[j], grid, assumed_s, tables[-1].clairvoyant,
                                    step_ms=1000.0 * args.step,
                                    second_step_ms=1000.0 * args.second_step,
                                    switches=args.switches))
    if args.tables is not None:
        rows = [t.to_json() for t in tables] + [t.to_json() for t in paths]
        write_text(args.tables, "".join(json.dumps(r) + "\n" for r in rows))
    first = best_capture(tables, args.budget, 0.0)
    print(f"stay_bound: {len(tables)} experiments of {args.folder.name} (stay {spec.text}, "
          f"{args.points} stays, clairvoyant saves {first.clairvoyant_ms / 1000:.2f} s mean), "
          f"best single replan vs the clairvoyant with worse <= {100 * args.budget:g}%: "
          + "; ".join([_line("from the block's report", first),
                       _line("from 1 s after it", best_capture(tables, args.budget, 1000.0)),
                       _line("from T_a", best_capture(tables, args.budget, None)),
                       *[_paths_line(paths, args.budget, k)
                         for k in range(1, args.switches + 1)]])
          + f" ({time.process_time() - began:.0f} s CPU)")


if __name__ == "__main__":
    run_main("bench/stay_bound.py", main)
