"""The clairvoyant sweep (exact against one fresh run per replan time, each informed of the
intruder's true cell and leave time) and its statistics by hand."""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from experiments.campaign import (
    CampaignSpec,
    PlanTask,
    SimSettings,
    load_grid,
    plan_instance,
    simulate_variant,
    variant_config,
)
from experiments.clairvoyant_stats import binomial_cdf, clopper_pearson_upper, summarize_outcomes
from experiments.oracle import read_oracle_rows, sweep
from gateway.execution.commands import SolveRequest
from gateway.execution.oneshot.policies import RandomReplan
from gateway.planning.grid import Grid
from gateway.planning.plan import Plan
from gateway.runtime.mapstore import resolve
from sim_clients.des import Simulation
from sim_clients.intruder import IntruderState
from tests.planning.fleetgate_cli import call

SIM = SimSettings(solver_time="zero", intruder_stay="uniform:1-30")
SPEC = CampaignSpec(groups=(("lab", 5),), instances=2, seeds=2, sim=SIM, plan_time_limit_s=20)
MAP = str(resolve("lab", "map"))


class _Knowing(Simulation):
    """A fresh run whose replan knows where the intruder is and when it leaves (the test's
    own reading of the clairvoyant, no memo, no fork)."""

    def plan_for(self, request: SolveRequest, now: float) -> tuple[Plan | None, float]:
        intr = self.intruder
        assert intr is not None
        if intr.state in (IntruderState.WAITING, IntruderState.PRESENT) \
                and intr.cell not in request.starts:
            assert intr.cell is not None
            request = dataclasses.replace(request, obstacles=((intr.cell, intr.leave_ms),))
        return super().plan_for(request, now)


def test_the_clairvoyant_sweep_equals_one_fresh_informed_run_per_replan_time() -> None:
    grid = load_grid(MAP)
    improved = 0
    for index in range(SPEC.instances):
        rec = plan_instance(PlanTask("lab", MAP, 5, index, 0, 20.0))
        for seed in SPEC.experiment_seeds("lab", 5, index):
            improved += _check_one(grid, rec.plan, seed)
    assert improved  # the clairvoyant found a better replan at least once


def _check_one(grid: Grid, plan: Plan, seed: int) -> bool:
    """One experiment's sweep against fresh runs; True if the clairvoyant saves."""
    config = variant_config(grid, plan, seed, "intruder", SIM)
    got = sweep(config, 500.0, clairvoyant=True)
    none = simulate_variant(grid, plan, seed, "intruder", SIM)
    assert got.none_soc_ms == none.soc_ms
    appear = SIM.intruder_appear_ms
    assert [t for t, _ in got.curve] == [appear + 500.0 * k for k in range(len(got.curve))]
    for t, soc in got.curve:
        sim = _Knowing(config)
        sim.executor.policy = RandomReplan(0, intruder_appear_ms=t, makespan_lb_ms=0.0)
        res = sim.run()
        assert (t, res.soc_ms) == (t, soc) and res.replan_at_ms == t
        # ... made while the intruder was there (the sweep stops once it is gone)
        assert sim.intruder is not None and t < sim.intruder.leave_ms + 500
    return got.best()[0] < got.none_soc_ms


def test_clopper_pearson_by_hand() -> None:
    # no failure in n: the bound solves (1 - p)^n = alpha
    for n in (10, 100, 1300):
        assert clopper_pearson_upper(0, n) == pytest.approx(1 - 0.05 ** (1 / n), abs=1e-9)
    # one in 10: P(X <= 1) = (1-p)^10 + 10 p (1-p)^9 = 0.05 at p = 0.39416 (tables)
    assert clopper_pearson_upper(1, 10) == pytest.approx(0.39416, abs=1e-5)
    assert clopper_pearson_upper(5, 5) == 1.0 and clopper_pearson_upper(0, 0) is None


@settings(max_examples=60, deadline=None)
@given(st.integers(1, 400), st.data())
def test_clopper_pearson_bound_is_where_the_tail_is_alpha(n: int, data: st.DataObject) -> None:
    k = data.draw(st.integers(0, n - 1))
    upper = clopper_pearson_upper(k, n)
    assert upper is not None and k / n < upper <= 1.0
    assert binomial_cdf(k, n, upper) == pytest.approx(0.05, abs=1e-6)
    assert upper >= (clopper_pearson_upper(k - 1, n) or 0.0) if k else True


def test_outcomes_by_hand() -> None:
    # four experiments: none, clairvoyant and policy SOCs (ms)
    t_n = np.array([100.0, 100.0, 100.0, 100.0])
    t_c = np.array([80.0, 90.0, 100.0, 60.0])
    t_x = np.array([90.0, 90.0, 103.0, 100.0])
    got = summarize_outcomes(t_n, t_x, t_c, seed=0, resamples=200)
    # pooled: (10 + 10 - 3 + 0) / (20 + 10 + 0 + 40) = 17 / 70
    assert got["capture"]["value"] == pytest.approx(17 / 70)
    # per experiment where the clairvoyant saves: 0.5, 1.0, 0.0 -> median 0.5
    assert got["capture_median"]["value"] == pytest.approx(0.5)
    worse = got["worse_than_none"]
    assert (worse["count"], worse["value"]) == (1, 0.25)
    assert worse["cost"]["max_ms"] == 3.0 and worse["cost"]["at_least_1s"] == 0
    assert worse["upper95"] == pytest.approx(clopper_pearson_upper(1, 4))
    assert got["saving_ms"]["value"] == pytest.approx(17 / 4)
    assert math.isclose(got["saving_ms"]["median"], 5.0)


def test_cli_clairvoyant_json(tmp_path: Path) -> None:
    out = tmp_path / "c"
    args = ["experiment", "--maps", "lab", "--agents", "5", "--instances", "1", "--seeds", "2",
            "--out", str(out), "--solver-time", "zero", "--intruder-stay", "uniform:1-30",
            "--shadow", "--clairvoyant", "--workers", "1", "--no-progress", "--json",
            "--resamples", "50"]
    done = call(*args)
    assert done.returncode == 0, done.stderr
    summary = json.loads(done.stdout)
    assert summary["campaign"]["intruder_stay"] == "uniform:1-30"
    c = summary["clairvoyant"]
    assert c["experiments"] == 2 and c["with_oracle"] == 0
    assert set(c["policies"]) == {"random", "slack", "shadow"}
    worse = c["policies"]["shadow"]["worse_than_none"]
    assert worse["upper95"] >= worse["value"] and "cost" in worse
    rows = read_oracle_rows(out / "clairvoyant.csv")
    assert len(rows) == 2 and all(r.best_soc_ms <= r.none_soc_ms for r in rows)
    # a rerun reuses the sweep: nothing swept again
    again = json.loads(call(*args).stdout)
    assert again["clairvoyant"]["cost"]["swept_now"] == 0
    # another stay is another campaign: the folder refuses it in one line
    other = call(*[a if a != "uniform:1-30" else "fixed:5" for a in args])
    assert other.returncode == 2 and "intruder_stay" in other.stderr
