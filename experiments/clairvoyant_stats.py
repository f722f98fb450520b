"""Each policy against the clairvoyant, and per-experiment outcomes (not only pooled ratios).

Per experiment: ``t_n`` the SOC without replanning, ``t_x`` policy X's, and ``t_c`` the
clairvoyant's: the best of not replanning, of one replan from ``T_a`` on that knows the
intruder's cell and leave time (:func:`experiments.oracle.sweep` with ``clairvoyant``), and,
when the oracle was swept too, of the oracle's uninformed replans from ``T_a`` on. Per policy:

* ``capture``: the pooled share of the clairvoyant's saving, ``Σ (t_n - t_x) / Σ (t_n - t_c)``
  (95 % bootstrap interval), and ``capture_median``: the median of ``(t_n - t_x) / (t_n - t_c)``
  over the experiments where the clairvoyant saves anything;
* ``worse_than_none``: the share of experiments with ``t_x > t_n``, its Wilson interval and
  its one-sided 95 % Clopper-Pearson upper bound, with the distribution of what those
  experiments cost (``t_x - t_n``);
* ``saving_ms``: the mean (bootstrap interval) and median of ``t_n - t_x``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from experiments.oracle import OracleRow
from experiments.oracle_stats import (
    Judged,
    as_value,
    capture_of,
    median_of,
    policies_run,
    policy_soc,
    share_of,
)
from experiments.stats import Experiment, describe_mean

JsonDict = dict[str, Any]


def binomial_cdf(k: int, n: int, p: float) -> float:
    """``P(X <= k)`` for ``X ~ Binomial(n, p)``."""
    if p <= 0.0:
        return 1.0
    if p >= 1.0:
        return 1.0 if k >= n else 0.0
    lp, lq = math.log(p), math.log1p(-p)
    return min(1.0, sum(math.exp(math.lgamma(n + 1) - math.lgamma(i + 1) - math.lgamma(n - i + 1)
                                 + i * lp + (n - i) * lq) for i in range(k + 1)))


def clopper_pearson_upper(k: int, n: int, alpha: float = 0.05) -> float | None:
    """The exact one-sided ``1 - alpha`` upper bound of a share seen ``k`` times in ``n``
    (Clopper-Pearson: the ``p`` with ``P(X <= k) = alpha``; None for no trials)."""
    if n == 0:
        return None
    if k >= n:
        return 1.0
    lo, hi = k / n, 1.0
    for _ in range(60):
        mid = (lo + hi) / 2
        if binomial_cdf(k, n, mid) > alpha:
            lo = mid
        else:
            hi = mid
    return hi


def clairvoyant_soc(exp: Experiment, clair: OracleRow, oracle: OracleRow | None) -> float:
    """``t_c``: the best of not replanning, the clairvoyant's replans and (if swept) the
    oracle's replans from ``T_a`` on."""
    best = min(exp.t_n, clair.best_soc_ms)
    if oracle is not None:
        best = min(best, oracle.best_after_appear_soc_ms)
    return best


def _losses(costs: Sequence[float]) -> JsonDict:
    if not costs:
        return {"n": 0, "median_ms": None, "mean_ms": None, "max_ms": None,
                "at_least_1s": 0}
    return {"n": len(costs), "median_ms": float(np.median(costs)),
            "mean_ms": float(np.mean(costs)), "max_ms": float(np.max(costs)),
            "at_least_1s": sum(1 for c in costs if c >= 1000.0)}


def summarize_outcomes(t_n: np.ndarray, t_x: np.ndarray, t_c: np.ndarray, *, seed: int,
                       resamples: int) -> JsonDict:
    """One policy's statistics (see the module's docstring) from the per-experiment SOCs."""
    possible = t_n - t_c
    saved = t_n - t_x
    shares = [float(saved[k] / possible[k]) for k in range(len(t_n)) if possible[k] > 0]
    worse = t_x > t_n
    hits, n = int(np.sum(worse)), len(t_n)
    share = share_of(hits, n)
    share["upper95"] = clopper_pearson_upper(hits, n)
    share["cost"] = _losses([float(c) for c in (t_x - t_n)[worse]])
    return {
        "capture": capture_of(saved, possible, seed=seed, resamples=resamples),
        "capture_median": median_of(shares, seed=seed, resamples=resamples),
        "worse_than_none": share,
        "saving_ms": as_value(describe_mean([float(v) for v in saved], seed=seed,
                                             resamples=resamples)),
    }


def summarize_clairvoyant(exps: Sequence[Experiment], clair: Sequence[OracleRow],
                          oracle: Sequence[OracleRow] = (), *, seed: int = 0,
                          resamples: int = 2000) -> JsonDict:
    """The ``clairvoyant`` block of ``summary.json``."""
    by_key = {r.key: r for r in clair}
    by_oracle = {r.key: r for r in oracle}
    joined = [(e, by_key[k], by_oracle.get(k)) for e in exps
              if (k := (e.map, e.agents, e.instance, e.seed)) in by_key]
    t_n = np.array([e.t_n for e, _, _ in joined], dtype=float)
    t_c = np.array([clairvoyant_soc(e, c, o) for e, c, o in joined], dtype=float)
    saving = t_n - t_c
    policies = policies_run([Judged(e, c) for e, c, _ in joined])
    return {
        "experiments": len(joined),
        "with_oracle": sum(1 for _, _, o in joined if o is not None),
        "clairvoyant": {
            "saves": share_of(int(np.sum(saving > 0)), len(joined)),
            "saving_ms": as_value(describe_mean([float(v) for v in saving], seed=seed,
                                                 resamples=resamples)),
        },
        "policies": {p: summarize_outcomes(
            t_n, np.array([policy_soc(e, p) for e, _, _ in joined], dtype=float), t_c,
            seed=seed, resamples=resamples) for p in policies},
    }
