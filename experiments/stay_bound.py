"""How much of the clairvoyant's saving a policy that does not know the stay could capture.

The clairvoyant (:mod:`experiments.oracle` with ``clairvoyant``) knows the intruder's cell and
leave time from the moment it appears. An online policy knows neither: it learns the cell
when a robot finds it taken (the block's first report, about ``T_a`` + 2 s) and, of the
stay, only that it has not ended yet. This module estimates the best such a policy could do
with one replan, per experiment, as a table of savings over a grid of stays:

* the stays: ``points`` equally likely stays, the midpoints of the distribution's quantile
  bins (:func:`stay_grid`), so a mean over the grid is an expectation over the stay;
* for each stay: the run without replanning, and every second from ``T_a`` while the
  intruder is there, a forced informed replan that keeps its cell free until the robot's
  need plus an *assumed* stay (each of ``assumed_s``, the same for every true stay: the
  policy cannot know it) and, as the clairvoyant, until the true leave time; the replan's
  waits for a reported block are gated as the executor's informed replans are (the robot
  moves in when the cell is really free, not at the assumed end);
* a policy picks, per experiment, one (replan time, assumed stay) or none; it replans only
  if the intruder is still there then (all it can observe), so its saving at a stay where
  the intruder left before is 0.

:func:`best_capture` then solves the campaign's choice: the largest pooled capture of the
clairvoyant's expected saving such that the expected share of experiments worse than not
replanning is at most ``budget`` (a Lagrangian relaxation of the choice, i.e. the linear
program that may mix two choices in one experiment: an upper bound for this family of
policies). The policy is allowed to know every experiment's savings table except the stay:
far more than any real policy knows. Policies that decide more than once (switch again,
replan back when the block ends early) are bounded by :mod:`experiments.stay_paths`.
"""

from __future__ import annotations

import dataclasses
import random
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from experiments.oracle import ClairvoyantSimulation, ExperimentKey, Memo
from sim_clients.des import SimConfig
from sim_clients.intruder import IntruderState
from sim_clients.stays import StaySpec

NONE = "none"
"""The label of not replanning."""


def stay_grid(spec: StaySpec, points: int, samples: int = 100_000) -> tuple[float, ...]:
    """``points`` equally likely stays (s) of ``spec``: the midpoints of its quantile bins,
    read from ``samples`` seeded draws."""
    rng = random.Random(20260)
    xs = sorted(spec.draw_s(rng) for _ in range(samples))
    return tuple(xs[min(samples - 1, int((k + 0.5) / points * samples))]
                 for k in range(points))


class Assumed(ClairvoyantSimulation):
    """A sweep fork whose forced replan keeps the intruder's cell free until its robot's
    need plus ``assumed_ms`` (the true stay when None: the clairvoyant)."""

    assumed_ms: float | None = None

    def _fingerprint(self, now: float) -> tuple[Any, ...]:
        # the new plan is a function of the cells and of the stay it assumes
        intr = self.intruder
        stay = None if intr is None else intr.config.stay_ms
        return (*super()._fingerprint(now), stay if self.assumed_ms is None else self.assumed_ms)

    def held_until(self, now: float) -> float:
        intr = self.intruder
        assert intr is not None
        if self.assumed_ms is None or intr.config.stay_ms is None:
            return intr.leave_ms
        return max(now + 1.0, intr.leave_ms - intr.config.stay_ms + self.assumed_ms)


@dataclass(frozen=True)
class GainTable:
    """One experiment's savings (ms, against not replanning) at each stay of the grid."""

    key: ExperimentKey
    need_ms: float | None
    """When the intruder's robot needed the cell (the block's first report; None: the
    intruder blocked nobody)."""
    clairvoyant: tuple[float, ...]
    """The best saving knowing the stay (0 if no replan saves)."""
    actions: dict[tuple[float, float], tuple[float, ...]]
    """``(replan time ms, assumed stay s)`` -> saving per stay."""

    def to_json(self) -> dict[str, Any]:
        """A JSON-able form (one line of the bench's output file)."""
        return {"key": list(self.key), "need_ms": self.need_ms,
                "clairvoyant": list(self.clairvoyant),
                "actions": [[t, a, list(g)] for (t, a), g in self.actions.items()]}

    @staticmethod
    def from_json(row: dict[str, Any]) -> GainTable:
        """The table of one line of the bench's output file (:meth:`to_json`)."""
        m, n, i, seed = row["key"]
        return GainTable((str(m), int(n), int(i), int(seed)), row["need_ms"],
                         tuple(row["clairvoyant"]),
                         {(float(t), float(a)): tuple(g) for t, a, g in row["actions"]})


def gain_table(config: SimConfig, key: ExperimentKey, stays_s: Sequence[float],
               assumed_s: Sequence[float], step_ms: float = 1000.0) -> GainTable:
    """The savings table of one experiment (``config``: its intruder variant, any stay)."""
    memo = Memo()
    socs: dict[tuple[float, float], list[float]] = {}
    best = []
    need: float | None = None
    for k, stay in enumerate(stays_s):
        cfg = dataclasses.replace(config, policy="none", max_replans=1, informed=True,
                                  intruder_stay=StaySpec("fixed", (stay,)))
        base = Assumed(cfg, memo)
        base.start()
        forks: dict[tuple[float, float | None], float] = {}
        t = cfg.intruder_config.appear_ms
        while True:
            base.run_until(t)
            intr = base.intruder
            if base.finished() or intr is None or intr.state is IntruderState.GONE:
                break
            for assumed in (None, *assumed_s):
                fork = base.fork(share=(memo,))
                fork.assumed_ms = None if assumed is None else 1000.0 * assumed
                fork.replan_now(t)
                fork.run_until(None)
                forks[(t, assumed)] = fork.outcome()[0]
            t += step_ms
        base.run_until(None)
        none = base.outcome()[0]
        intr = base.intruder
        if intr is not None and intr.cell is not None and intr.config.stay_ms is not None:
            need = intr.leave_ms - intr.config.stay_ms
        best.append(max([0.0] + [none - s for (_, a), s in forks.items() if a is None]))
        for (t, a), s in forks.items():
            if a is not None:
                socs.setdefault((t, a), [0.0] * len(stays_s))[k] = none - s
    return GainTable(key, need, tuple(best), {ta: tuple(g) for ta, g in socs.items()})


@dataclass(frozen=True)
class Bound:
    """The best capture of the family (see the module's docstring)."""

    experiments: int
    clairvoyant_ms: float
    """The clairvoyant's mean expected saving per experiment."""
    capture: float
    """Pooled capture of the best choice with the worse-than-none share within the budget."""
    worse: float
    """Its expected worse-than-none share."""
    never_losing: float
    """Pooled capture of the best choice that loses at no stay of the grid."""
    median: float | None
    """Median per-experiment capture (expected savings) of the budgeted choice, over the
    experiments where the clairvoyant saves."""


Options = list[tuple[float, float]]
"""An experiment's choices: ``(expected saving ms, chance of being worse than none)`` each."""


def best_capture(tables: Sequence[GainTable], budget: float,
                 not_before_need_ms: float | None = 0.0) -> Bound:
    """The best capture of policies that replan once, at or after the block's first report
    plus ``not_before_need_ms`` (None: from ``T_a``, knowing the cell as early as the
    clairvoyant), with an expected worse-than-none share of at most ``budget``."""
    options, clair = [], []
    for tab in tables:
        opts = [(0.0, 0.0)]
        for (t, _), g in tab.actions.items():
            if not_before_need_ms is not None and (
                    tab.need_ms is None or t < tab.need_ms + not_before_need_ms):
                continue
            arr = np.asarray(g)
            opts.append((float(arr.mean()), float((arr < 0).mean())))
        options.append(opts)
        clair.append(float(np.mean(tab.clairvoyant)))
    capture, worse, median = choose_capture(options, clair, budget)
    safe = choose_capture(options, clair, 0.0)[0]
    n = len(tables)
    return Bound(n, sum(clair) / n if n else 0.0, capture, worse, safe, median)


def choose_capture(options: Sequence[Options], clairvoyant_ms: Sequence[float],
                   budget: float) -> tuple[float, float, float | None]:
    """The campaign's choice, one of ``options`` per experiment (the first must be not
    replanning, ``(0, 0)``), that maximises the pooled capture of the clairvoyant's expected
    savings ``clairvoyant_ms`` with an expected worse-than-none share of at most ``budget``:
    the linear program that may mix two choices in one experiment, solved by its Lagrangian.
    Returns the pooled capture, the worse-than-none share and the median per-experiment
    capture over the experiments where the clairvoyant saves."""
    gains = [np.asarray([o[0] for o in opts]) for opts in options]
    risks = [np.asarray([o[1] for o in opts]) for opts in options]
    n, total = len(options), float(sum(clairvoyant_ms))

    def pick(lam: float) -> tuple[float, float, list[int]]:
        chosen = [int(np.argmax(e - lam * p)) for e, p in zip(gains, risks, strict=True)]
        return (sum(float(e[j]) for e, j in zip(gains, chosen, strict=True)),
                sum(float(p[j]) for p, j in zip(risks, chosen, strict=True)), chosen)

    lo, hi = 0.0, 1e12
    if pick(lo)[1] <= budget * n:
        hi = lo
    else:
        for _ in range(200):
            mid = (lo + hi) / 2
            lo, hi = (lo, mid) if pick(mid)[1] <= budget * n else (mid, hi)
    e_hi, p_hi, chosen = pick(hi if budget > 0 else 1e15)
    e_lo, p_lo, _ = pick(lo)
    w = 0.0 if p_lo <= p_hi else min(1.0, max(0.0, (budget * n - p_hi) / (p_lo - p_hi)))
    saving, worse = w * e_lo + (1 - w) * e_hi, w * p_lo + (1 - w) * p_hi
    shares = [float(e[j]) / c for e, j, c in zip(gains, chosen, clairvoyant_ms, strict=True)
              if c > 0]
    return (saving / total if total > 0 else 0.0, worse / n if n else 0.0,
            float(np.median(shares)) if shares else None)
