"""How much of the clairvoyant's saving can any online policy capture, at most?
(:mod:`experiments.stay_info`; not a timed test.)

Reads a campaign folder of ``fleetgate experiment`` and, for each of its experiments (or a
seeded ``--sample``), runs the clairvoyant sweep (the campaign's own yardstick, same step) and
notes when the fleet first reported the intruder's block. It prints one line: the pooled and
median capture of the clairvoyant's saving (the baseline, measured in the same run) by the same
yardstick allowed to replan only from that first report, still knowing the stay exactly, with
bootstrap 95% intervals over experiments; and the same when it may instead take the
uninformed oracle's best replan (``oracle.csv`` of the folder, if there). Every online policy
that replans with informed solves learns the cell no earlier and the stay no better, so these
captures bound it from above.
"""

from __future__ import annotations

import fleetgate.userio.script  # noqa: F401 (first: Ctrl-C while importing is one line)

# isort: split

import json
import time
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from experiments.campaign import InstanceRecord, SimSettings, load_grid, variant_config
from experiments.oracle import DEFAULT_STEP_MS, read_oracle_rows
from experiments.stay_info import ReportSweep, report_sweep
from fleetgate.userio.exits import CommandParser, run_main
from gateway.planning.seeds import derive_seed
from gateway.runtime.exits import UsageError
from gateway.runtime.mapstore import MapNotFound, resolve

Key = tuple[str, int, int, int]


def capture(part: np.ndarray, whole: np.ndarray) -> tuple[float, float]:
    """Pooled capture (ratio of sums) and median per-experiment capture over the experiments
    where ``whole`` saves."""
    total = float(whole.sum())
    saves = whole > 0
    pooled = float(part.sum()) / total if total > 0 else 0.0
    median = float(np.median(part[saves] / whole[saves])) if saves.any() else 0.0
    return pooled, median


def interval(part: np.ndarray, whole: np.ndarray, seed: int,
             rounds: int = 2000) -> tuple[tuple[float, float], tuple[float, float]]:
    """Bootstrap 95% intervals (over experiments) of :func:`capture`'s two figures."""
    rng = np.random.default_rng(seed)
    n = len(whole)
    got = np.array([capture(part[j], whole[j]) for j in
                    (rng.integers(0, n, n) for _ in range(rounds))])
    lo, hi = np.percentile(got, [2.5, 97.5], axis=0)
    return (float(lo[0]), float(hi[0])), (float(lo[1]), float(hi[1]))


def _figure(label: str, part: np.ndarray, whole: np.ndarray, seed: int) -> str:
    (p, m), ((plo, phi), (mlo, mhi)) = capture(part, whole), interval(part, whole, seed)
    return (f"{label}: pooled {100 * p:.1f}% ({100 * plo:.1f}-{100 * phi:.1f}), median "
            f"{100 * m:.1f}% ({100 * mlo:.1f}-{100 * mhi:.1f})")


def _keys(folder: Path) -> list[Key]:
    try:
        rows = (folder / "results.csv").read_text().splitlines()[1:]
        return sorted({(r[0], int(r[1]), int(r[2]), int(r[3]))
                       for r in (line.split(",") for line in rows) if r[4] == "intruder"})
    except (OSError, ValueError, IndexError) as exc:
        raise UsageError(f"{folder}: not a campaign folder ({exc})") from None


def _sweeps(folder: Path, keys: Sequence[Key], sim: SimSettings, maps_dir: str | None,
            step_ms: float) -> list[ReportSweep]:
    out = []
    for m, n, i, seed in keys:
        try:
            rec = InstanceRecord.from_json(json.loads(
                (folder / "instances" / f"{m}-{n}-{i:03d}.json").read_text()))
            path = resolve(m, "map", maps_dir)
        except (OSError, ValueError, KeyError, MapNotFound) as exc:
            raise UsageError(f"{folder}: {m}-{n}-{i}: {exc}") from None
        out.append(report_sweep(variant_config(load_grid(str(path)), rec.plan, seed,
                                               "intruder", sim), step_ms))
    return out


def main() -> None:
    """Sweep the experiments and print the result line."""
    p = CommandParser(description=__doc__)
    p.add_argument("folder", type=Path, help="a fleetgate experiment --out folder")
    p.add_argument("--sample", type=int, default=0, help="experiments (default 0: all)")
    p.add_argument("--step", type=float, default=DEFAULT_STEP_MS / 1000.0,
                   help="seconds between the sweep's replans (default the oracle's)")
    p.add_argument("--maps-dir", default=None)
    p.add_argument("--json", action="store_true", help="also print each experiment's figures")
    args = p.parse_args()
    if not (args.sample >= 0 and args.step > 0):
        raise UsageError("need --sample >= 0 and --step > 0")
    try:
        settings = json.loads((args.folder / "campaign.json").read_text())
    except (OSError, ValueError) as exc:
        raise UsageError(f"{args.folder}: not a campaign folder ({exc})") from None
    keys = _keys(args.folder)
    seed = derive_seed(int(settings.get("seed", 0)), "stay-info")
    if args.sample:
        rng = np.random.default_rng(seed)
        keys = [keys[j] for j in sorted(rng.permutation(len(keys))[:args.sample].tolist())]
    sim = SimSettings(solver_time="zero", intruder_appear_ms=settings["intruder_appear_ms"],
                      intruder_leave_ms=settings["intruder_leave_ms"],
                      intruder_reading=settings["intruder_reading"],
                      intruder_stay=settings.get("intruder_stay"))
    began = time.process_time()
    got = _sweeps(args.folder, keys, sim, args.maps_dir, 1000.0 * args.step)
    whole = np.array([g.saving_ms() for g in got])
    report = np.array([g.saving_ms(from_report=True) for g in got])
    parts = [_figure("acting from the first report, knowing the stay", report, whole, seed)]
    try:
        oracle = {r.key: r.none_soc_ms - r.best_soc_ms
                  for r in read_oracle_rows(args.folder / "oracle.csv")}
    except ValueError as exc:
        raise UsageError(str(exc)) from None
    if oracle and all(k in oracle for k in keys):
        either = np.maximum(report, [max(0.0, oracle[k]) for k in keys])
        parts.append(_figure("or the uninformed oracle's replan", either, whole, seed))
    if args.json:
        for k, g, w, r in zip(keys, got, whole, report, strict=True):
            print(json.dumps({"key": list(k), "stay_ms": g.stay_ms,
                              "first_report_ms": g.first_report_ms, "clairvoyant_ms": w,
                              "from_report_ms": r}))
    print(f"stay_info: {len(got)} experiments of {args.folder.name} (stay "
          f"{settings.get('intruder_stay') or 'the paper'}'s, clairvoyant saves "
          f"{whole.mean() / 1000:.2f} s mean, step {args.step:g} s), capture of the "
          f"clairvoyant's saving, bootstrap 95%: " + "; ".join(parts)
          + f" ({time.process_time() - began:.0f} s CPU)")


if __name__ == "__main__":
    run_main("bench/stay_info.py", main)
