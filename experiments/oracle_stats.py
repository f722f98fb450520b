"""How much of what replanning could save each policy saves, against the oracle.

Per experiment: ``t_n`` the SOC without replanning, ``t_o`` the oracle's (the best single
replan, or none: ``t_o <= t_n``), ``t_x`` policy X's, ``t_lb`` the lower bound. Per policy:

* ``capture``: the pooled share of the oracle's saving, ``Σ (t_n - t_x) / Σ (t_n - t_o)``;
* ``capture_median``: the median of ``(t_n - t_x) / (t_n - t_o)`` over experiments where the
  oracle saves anything;
* ``worse_than_none``: the share of experiments where X's SOC is above ``t_n``;
* ``mitigation``: the mean of ``(t_n - t_x) / (t_n - t_lb)`` where X replanned (decided to),
  beside the oracle's on the same experiments (``oracle_mitigation``);
* ``replanned``: the share of experiments where X decided to replan;
* ``trigger_minus_best_ms``: X's replan time minus the oracle's best replan time.

Intervals are 95 %: a percentile bootstrap over experiments (seeded) for ratios, means and
medians, Wilson's score interval for shares.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from experiments.campaign import EXTRA_VARIANTS
from experiments.oracle import CAVEATS, OracleRow
from experiments.stats import Experiment, describe_mean, extras_run, mitigation

JsonDict = dict[str, Any]

POLICIES: tuple[str, ...] = ("random", "slack", *EXTRA_VARIANTS)
"""The campaign's replanning variants, compared with the oracle (the extra ones when run)."""


@dataclass(frozen=True)
class Judged:
    """One experiment with its oracle."""

    exp: Experiment
    oracle: OracleRow

    @property
    def t_o(self) -> float:
        """The oracle's SOC (never above not replanning)."""
        return min(self.oracle.best_soc_ms, self.exp.t_n)

    @property
    def oracle_saving(self) -> float:
        """``t_n - t_o``, at least 0."""
        return self.exp.t_n - self.t_o


def policy_soc(exp: Experiment, policy: str) -> float:
    """The SOC of ``policy``'s variant."""
    if policy == "random":
        return exp.t_r
    if policy == "slack":
        return exp.t_p
    return exp.extra[policy][0]


def policy_replanned(exp: Experiment, policy: str) -> tuple[bool, float | None]:
    """Whether ``policy`` decided to replan, and when."""
    if policy == "random":
        return exp.random_replanned, exp.random_at_ms
    if policy in exp.extra:
        at = exp.extra[policy][1]
        return at is not None, at
    return exp.slack_replanned, exp.slack_at_ms


def policies_run(judged: Sequence[Judged]) -> tuple[str, ...]:
    """The policies every experiment of ``judged`` ran."""
    extras = extras_run([j.exp for j in judged])
    return tuple(p for p in POLICIES if p in ("random", "slack") or p in extras)


def wilson(successes: int, n: int, z: float = 1.959964) -> tuple[float, float] | None:
    """Wilson's score interval of a share (None for no trials)."""
    if n == 0:
        return None
    p = successes / n
    centre = (p + z * z / (2 * n)) / (1 + z * z / n)
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / (1 + z * z / n)
    return max(0.0, centre - half), min(1.0, centre + half)


def bootstrap(n: int, stat: Callable[[np.ndarray], float | None], *, seed: int,
              resamples: int) -> tuple[float, float] | None:
    """Percentile 95 % interval of ``stat(indices)`` over experiments resampled with
    replacement (resamples where ``stat`` is undefined are skipped)."""
    if n == 0:
        return None
    rng = np.random.default_rng(seed)
    got = [v for idx in rng.integers(0, n, size=(resamples, n))
           if (v := stat(idx)) is not None and math.isfinite(v)]
    if not got:
        return None
    lo, hi = np.percentile(got, [2.5, 97.5])
    return float(lo), float(hi)


def share_of(hits: int, n: int) -> JsonDict:
    """``hits`` of ``n`` as a share with its Wilson 95 % interval."""
    ci = wilson(hits, n)
    return {"value": hits / n if n else None, "ci95": list(ci) if ci else None, "n": n,
            "count": hits}


def capture_of(saved: np.ndarray, possible: np.ndarray, *, seed: int,
               resamples: int) -> JsonDict:
    """The pooled share ``sum(saved) / sum(possible)`` with its bootstrap 95 % interval."""

    def pooled(idx: np.ndarray) -> float | None:
        total = float(possible[idx].sum())
        return float(saved[idx].sum()) / total if total > 0 else None

    ci = bootstrap(len(saved), pooled, seed=seed, resamples=resamples)
    return {"value": pooled(np.arange(len(saved))), "ci95": list(ci) if ci else None,
            "n": len(saved)}


def median_of(values: Sequence[float], *, seed: int, resamples: int) -> JsonDict:
    """The median of ``values`` with its bootstrap 95 % interval."""
    data = np.asarray(values, dtype=float)

    def med(idx: np.ndarray) -> float | None:
        return float(np.median(data[idx]))

    ci = bootstrap(len(data), med, seed=seed, resamples=resamples)
    return {"value": float(np.median(data)) if len(data) else None,
            "ci95": list(ci) if ci else None, "n": len(data)}


def as_value(d: JsonDict) -> JsonDict:
    """:func:`describe_mean`'s dict in this module's shape (``value`` is the mean)."""
    return {"value": d["mean"], "ci95": d["ci95"], "n": d["n"], "median": d["median"]}


def judge(exps: Sequence[Experiment], oracle: Sequence[OracleRow]) -> list[Judged]:
    """The experiments that have an oracle row, joined with it."""
    by_key = {r.key: r for r in oracle}
    return [Judged(e, by_key[k]) for e in exps
            if (k := (e.map, e.agents, e.instance, e.seed)) in by_key]


def summarize_policy(judged: Sequence[Judged], policy: str, *, seed: int = 0,
                     resamples: int = 2000) -> JsonDict:
    """Every oracle statistic of one policy (see the module's docstring)."""
    t_n = np.array([j.exp.t_n for j in judged], dtype=float)
    t_x = np.array([policy_soc(j.exp, policy) for j in judged], dtype=float)
    possible = np.array([j.oracle_saving for j in judged], dtype=float)
    shares = [(float(t_n[k] - t_x[k]) / float(possible[k])) for k in range(len(judged))
              if possible[k] > 0]
    replanned = [j for j in judged if policy_replanned(j.exp, policy)[0]]
    mit_x, mit_o = [], []
    for j in replanned:
        mx = mitigation(j.exp.t_n, policy_soc(j.exp, policy), j.exp.t_lb)
        mo = mitigation(j.exp.t_n, j.t_o, j.exp.t_lb)
        if mx is not None and mo is not None:
            mit_x.append(mx)
            mit_o.append(mo)
    leads = []
    for j in replanned:
        at = policy_replanned(j.exp, policy)[1]
        if at is not None and j.oracle.best_at_ms is not None:
            leads.append(at - j.oracle.best_at_ms)
    return {
        "capture": capture_of(t_n - t_x, possible, seed=seed, resamples=resamples),
        "capture_median": median_of(shares, seed=seed, resamples=resamples),
        "worse_than_none": share_of(int(np.sum(t_x > t_n)), len(judged)),
        "mitigation": as_value(describe_mean(mit_x, seed=seed, resamples=resamples)),
        "oracle_mitigation": as_value(describe_mean(mit_o, seed=seed, resamples=resamples)),
        "replanned": share_of(len(replanned), len(judged)),
        "trigger_minus_best_ms": as_value(describe_mean(leads, seed=seed,
                                                         resamples=resamples)),
    }


def summarize_oracle(exps: Sequence[Experiment], oracle: Sequence[OracleRow], *,
                     appear_ms: float, seed: int = 0, resamples: int = 2000) -> JsonDict:
    """The ``oracle`` block of ``summary.json``."""
    judged = judge(exps, oracle)
    influenced = [j for j in judged if j.exp.influence_ms > 0]
    mit = [(j.exp.t_n - j.t_o) / j.exp.influence_ms for j in influenced]
    after = [(j.exp.t_n - min(j.oracle.best_after_appear_soc_ms, j.exp.t_n))
             / j.exp.influence_ms for j in influenced]
    saving = [j.oracle_saving for j in judged]
    best_at = [j.oracle.best_at_ms for j in judged if j.oracle.best_at_ms is not None]
    cpu = [j.oracle.cpu_s for j in judged]
    return {
        "experiments": len(judged),
        "step_ms": judged[0].oracle.step_ms if judged else None,
        "oracle": {
            "saves": share_of(sum(1 for s in saving if s > 0), len(judged)),
            "saving_ms": as_value(describe_mean(saving, seed=seed, resamples=resamples)),
            "mitigation": as_value(describe_mean(mit, seed=seed, resamples=resamples)),
            "mitigation_after_appear": as_value(describe_mean(after, seed=seed,
                                                               resamples=resamples)),
            "best_before_appear": share_of(sum(1 for t in best_at if t < appear_ms),
                                         len(best_at)),
            "best_at_minus_appear_ms": as_value(describe_mean(
                [t - appear_ms for t in best_at], seed=seed, resamples=resamples)),
        },
        "policies": {p: summarize_policy(judged, p, seed=seed, resamples=resamples)
                     for p in policies_run(judged)},
        "cost": {"cpu_s_total": round(sum(cpu), 3),
                 "cpu_s_mean": float(np.mean(cpu)) if cpu else None,
                 "replans": sum(j.oracle.replans for j in judged),
                 "solves": sum(j.oracle.solves for j in judged),
                 "continuations": sum(j.oracle.continuations for j in judged)},
        "caveats": list(CAVEATS),
    }


def extrapolate_cpu_s(oracle: Sequence[OracleRow],
                      groups: Sequence[tuple[str, int]], per_group: int) -> float | None:
    """The CPU seconds a sweep of ``per_group`` experiments of every group would take, from
    the measured mean per group; None unless every group was measured."""
    total = 0.0
    for m, n in groups:
        got = [r.cpu_s for r in oracle if (r.map, r.agents) == (m, n)]
        if not got:
            return None
        total += per_group * float(np.mean(got))
    return total
