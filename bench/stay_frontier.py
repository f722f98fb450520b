"""The stay bound against the worse-than-none budget, from saved savings tables.
(:mod:`experiments.stay_bound`, :mod:`experiments.stay_paths`; not a timed test.)

Reads the tables ``bench/stay_bound.py --tables FILE`` wrote (with ``--switches``, the path
tables too) and prints one line: for each budget of ``--budgets`` (the largest expected share
of experiments worse than not replanning), the best pooled capture of the clairvoyant's
expected saving (the baseline, from the same tables) by one replan from the block's first
report and, if the file has them, by the paths of up to two switches with the replan back,
each with a bootstrap 95% interval over experiments (``--rounds`` resamples, seeded).
"""

from __future__ import annotations

import fleetgate.userio.script  # noqa: F401 (first: Ctrl-C while importing is one line)

# isort: split

import json
from collections.abc import Callable, Sequence
from functools import partial
from pathlib import Path
from typing import TypeVar

import numpy as np

from experiments.stay_bound import GainTable, best_capture
from experiments.stay_paths import PathTable, best_path_capture
from fleetgate.userio.exits import CommandParser, run_main
from gateway.runtime.exits import UsageError

T = TypeVar("T")


def _figure(tables: Sequence[T], capture: Callable[[Sequence[T]], float], rounds: int,
            seed: int) -> str:
    """``capture`` of ``tables`` with its bootstrap 95% interval over the tables."""
    rng = np.random.default_rng(seed)
    n = len(tables)
    got = [capture([tables[j] for j in rng.integers(0, n, n)]) for _ in range(rounds)]
    lo, hi = np.percentile(got, [2.5, 97.5])
    return f"{100 * capture(tables):.1f}% ({100 * lo:.0f}-{100 * hi:.0f})"


def _one_replan(budget: float, tables: Sequence[GainTable]) -> float:
    return best_capture(tables, budget, 0.0).capture


def _two_switches(budget: float, tables: Sequence[PathTable]) -> float:
    return best_path_capture(tables, budget, 2)[0]


def main() -> None:
    """Read the tables and print the result line."""
    p = CommandParser(description=__doc__)
    p.add_argument("tables", type=Path, help="a bench/stay_bound.py --tables file")
    p.add_argument("--budgets", default="0,0.01,0.05,0.2,1",
                   help="worse-than-none budgets, comma-separated (default 0,0.01,0.05,0.2,1)")
    p.add_argument("--rounds", type=int, default=200, help="bootstrap resamples (default 200)")
    args = p.parse_args()
    try:
        budgets = [float(b) for b in args.budgets.split(",")]
        rows = [json.loads(line) for line in args.tables.read_text().splitlines() if line]
        gains = [GainTable.from_json(r) for r in rows if "actions" in r]
        paths = [PathTable.from_json(r) for r in rows if "paths" in r]
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise UsageError(f"{args.tables}: not a stay_bound tables file ({exc})") from None
    if not (gains and all(0 <= b <= 1 for b in budgets) and args.rounds >= 1):
        raise UsageError("need a tables file with gain tables, budgets in [0, 1] and "
                         "--rounds >= 1")
    parts = []
    for b in budgets:
        part = f"budget {100 * b:g}%: one replan " + _figure(
            gains, partial(_one_replan, b), args.rounds, 1)
        if paths:
            part += ", 2 switches + back " + _figure(
                paths, partial(_two_switches, b), args.rounds, 2)
        parts.append(part)
    clair = float(np.mean([np.mean(t.clairvoyant) for t in gains]))
    print(f"stay_frontier: {len(gains)} experiments of {args.tables.name} (clairvoyant saves "
          f"{clair / 1000:.2f} s mean), best capture of the clairvoyant's saving with at most "
          f"the budget worse than none, bootstrap 95%: " + "; ".join(parts))


if __name__ == "__main__":
    run_main("bench/stay_frontier.py", main)
