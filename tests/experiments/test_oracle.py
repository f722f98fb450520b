"""The oracle sweep: exact against one fresh simulation per replan time, its statistics by hand,
and ``fleetgate experiment --oracle`` end to end (lab, 5 robots, solver time charged as zero)."""

from __future__ import annotations

import dataclasses
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from experiments.campaign import (
    CampaignSpec,
    InstanceRecord,
    SimSettings,
    load_grid,
    open_executor,
    read_results,
    run_campaign,
    simulate_variant,
    variant_config,
)
from experiments.oracle import OracleRow, Sweep, read_oracle_rows, sample_experiments, sweep
from experiments.oracle_stats import judge, summarize_policy, wilson
from experiments.stats import Experiment, join_experiments
from gateway.execution.oneshot.policies import RandomReplan
from gateway.runtime.mapstore import resolve
from sim_clients.des import Simulation

SIM = SimSettings(solver_time="zero")
SPEC = CampaignSpec(groups=(("lab", 5),), instances=2, seeds=2, sim=SIM, plan_time_limit_s=20)
MAPS = {"lab": str(resolve("lab", "map"))}


def _replan_at(t_ms: float) -> RandomReplan:
    """A policy that replans once at ``t_ms`` (an empty random interval starts there)."""
    return RandomReplan(0, intruder_appear_ms=t_ms, makespan_lb_ms=0.0)


@pytest.fixture(scope="module")
def campaign(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict[tuple[str, int, int],
                                                                          InstanceRecord]]:
    out = tmp_path_factory.mktemp("oracle")
    with open_executor(1) as (pool, n):
        res = run_campaign(SPEC, out, MAPS, executor=pool, workers=n)
    return out, res.records


def test_the_memoised_sweep_equals_one_fresh_run_per_replan_time(campaign: tuple[
        Path, dict[tuple[str, int, int], InstanceRecord]]) -> None:
    grid = load_grid(MAPS["lab"])
    improved = 0
    for (m, n, i), rec in sorted(campaign[1].items()):
        for seed in SPEC.experiment_seeds(m, n, i):
            config = variant_config(grid, rec.plan, seed, "intruder", SIM)
            got = sweep(config, 500.0)
            # Not replanning: the campaign's intruder variant.
            none = simulate_variant(grid, rec.plan, seed, "intruder", SIM)
            assert got.none_soc_ms == none.soc_ms
            # Every step until the run without a replan ends.
            assert [t for t, _ in got.curve] == [500.0 * k for k in range(len(got.curve))]
            assert got.curve[-1][0] < none.makespan_ms <= got.curve[-1][0] + 500
            # The memos did their work ...
            assert got.solves < len(got.curve) and got.continuations < len(got.curve)
            # ... and changed nothing: each point is a whole run with a policy firing then.
            for t, soc in got.curve:
                sim = Simulation(config)
                sim.executor.policy = _replan_at(t)
                res = sim.run()
                assert (t, res.soc_ms) == (t, soc) and res.replan_at_ms == t
            soc, at = got.best()
            assert soc == min([got.none_soc_ms, *(s for _, s in got.curve)])
            assert at is None if soc == got.none_soc_ms else (at, soc) in got.curve
            improved += soc < got.none_soc_ms
    assert improved  # the oracle found a better replan at least once


def test_the_informed_variant_adds_rows_to_a_finished_folder(campaign: tuple[
        Path, dict[tuple[str, int, int], InstanceRecord]], tmp_path: Path) -> None:
    shutil.copytree(campaign[0], tmp_path / "c")
    before = read_results(tmp_path / "c" / "results.csv")
    spec = dataclasses.replace(SPEC, extra_variants=("informed",))
    with open_executor(1) as (pool, n):
        res = run_campaign(spec, tmp_path / "c", MAPS, executor=pool, workers=n)
    assert (res.planned, res.ran, res.complete) == (0, 4, True)
    rows = read_results(tmp_path / "c" / "results.csv")
    assert [r for r in rows if r.variant != "informed"] == before
    exps, _ = join_experiments(rows)
    for e in exps:
        # Informed replans exactly when slack does (the same trigger on the same run).
        assert e.extra["informed"][1] == e.slack_at_ms
        if e.slack_at_ms is None:
            assert e.extra["informed"][0] == e.t_p == e.t_n


def test_best_prefers_not_replanning_then_the_earliest() -> None:
    s = Sweep(10_000.0, ((0.0, 12_000.0), (250.0, 9_000.0), (500.0, 9_000.0),
                         (3_000.0, 9_500.0)), 2, 2)
    assert s.best() == (9_000.0, 250.0)
    assert s.best(not_before_ms=300.0) == (9_000.0, 500.0)
    assert s.best(not_before_ms=1_000.0) == (9_500.0, 3_000.0)
    assert Sweep(10_000.0, ((0.0, 10_000.0),), 1, 1).best() == (10_000.0, None)


def test_sweep_refuses_a_policy_of_its_own(campaign: tuple[Path, dict[tuple[str, int, int],
                                                                      InstanceRecord]]) -> None:
    rec = campaign[1][("lab", 5, 0)]
    config = variant_config(load_grid(MAPS["lab"]), rec.plan, 1, "slack", SIM)
    with pytest.raises(ValueError, match="policy 'none'"):
        sweep(config)
    with pytest.raises(ValueError, match="positive"):
        sweep(variant_config(load_grid(MAPS["lab"]), rec.plan, 1, "intruder", SIM), 0.0)


def _exp(i: int, t_n: float, t_r: float, t_p: float, slack_at: float | None) -> Experiment:
    return Experiment("m", 5, i, 0, t_lb=1000.0, t_n=t_n, t_r=t_r, t_p=t_p,
                      slack_replanned=slack_at is not None, random_replanned=True,
                      slack_at_ms=slack_at, random_at_ms=4000.0, slack_solver_ms=0.0,
                      random_solver_ms=0.0)


def _oracle(i: int, best: float, at: float | None) -> OracleRow:
    return OracleRow("m", 5, i, 0, 250.0, 0.0, best, at, best, at, 10, 3, 3, 0.5)


def test_policy_statistics_by_hand() -> None:
    # t_lb = 1000 everywhere. Oracle savings 1000, 500, 0; slack saves 800, -100 (worse
    # than not replanning), 0 (kept the plan).
    exps = [_exp(0, 3000.0, 2900.0, 2200.0, 5000.0), _exp(1, 2000.0, 2000.0, 2100.0, 6000.0),
            _exp(2, 2000.0, 2000.0, 2000.0, None)]
    rows = [_oracle(0, 2000.0, 4500.0), _oracle(1, 1500.0, 7000.0), _oracle(2, 2500.0, None)]
    judged = judge(exps, rows)
    assert [j.oracle_saving for j in judged] == [1000.0, 500.0, 0.0]  # the oracle >= none
    slack = summarize_policy(judged, "slack", resamples=200)
    assert slack["capture"]["value"] == pytest.approx((800 - 100) / 1500)
    assert slack["capture_median"]["value"] == pytest.approx((0.8 - 0.2) / 2)
    assert slack["worse_than_none"]["value"] == pytest.approx(1 / 3)
    assert slack["worse_than_none"]["count"] == 1
    assert slack["replanned"]["value"] == pytest.approx(2 / 3)
    # Mitigation where slack replanned: (3000-2200)/2000 and (2000-2100)/1000.
    assert slack["mitigation"]["value"] == pytest.approx((0.4 - 0.1) / 2)
    assert slack["oracle_mitigation"]["value"] == pytest.approx((0.5 + 0.5) / 2)
    assert slack["trigger_minus_best_ms"]["median"] == pytest.approx((500 - 1000) / 2)
    lo, hi = slack["capture"]["ci95"]
    assert lo <= slack["capture"]["value"] <= hi
    rnd = summarize_policy(judged, "random", resamples=200)
    assert rnd["capture"]["value"] == pytest.approx(100 / 1500)
    assert rnd["worse_than_none"]["value"] == 0.0


def test_wilson_interval() -> None:
    lo, hi = wilson(0, 10)  # type: ignore[misc]
    assert lo == 0.0 and hi == pytest.approx(1.959964**2 / (10 + 1.959964**2))
    lo, hi = wilson(5, 10)  # type: ignore[misc]
    assert lo == pytest.approx(1 - hi)
    assert wilson(0, 0) is None


def test_samples_are_seeded_nested_and_in_order() -> None:
    keys = [("m", 5, i, 0) for i in range(50)]
    small, large = sample_experiments(keys, 10, 0), sample_experiments(keys, 30, 0)
    assert len(small) == 10 and set(small) <= set(large) and small == sorted(small)
    assert sample_experiments(keys, 10, 0) == small != sample_experiments(keys, 10, 1)
    assert sample_experiments(keys, None, 0) == keys == sample_experiments(keys, 99, 0)


def test_cli_oracle_json_csv_plot_and_resume(campaign: tuple[Path, object],
                                             tmp_path: Path) -> None:
    out = tmp_path / "cli"
    cmd = [str(Path(sys.executable).with_name("fleetgate")), "experiment", "--maps", "lab",
           "--agents", "5", "--instances", "2", "--seeds", "2", "--solver-time", "zero",
           "--plan-time-limit", "20", "--out", str(out), "--workers", "1", "--no-progress",
           "--oracle", "--oracle-sample", "3", "--oracle-step-ms", "500", "--resamples", "200",
           "--informed"]
    done = subprocess.run([*cmd, "--json"], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    summary = json.loads(done.stdout)
    oracle = summary["oracle"]
    assert oracle["experiments"] == 3 and oracle["step_ms"] == 500
    assert list(oracle["policies"]) == ["random", "slack", "informed"]
    for policy in ("random", "slack", "informed"):
        got = oracle["policies"][policy]
        for key in ("capture", "capture_median", "worse_than_none", "mitigation", "replanned"):
            assert set(got[key]) >= {"value", "ci95", "n"}
        assert got["replanned"]["n"] == 3
    assert oracle["caveats"] and oracle["cost"]["swept_now"] == 3
    rows = read_oracle_rows(out / "oracle.csv")
    assert len(rows) == 3 and all(r.best_soc_ms <= r.none_soc_ms for r in rows)
    assert (out / "oracle.png").stat().st_size > 5000
    # A rerun sweeps nothing again and prints the tables and the caveats.
    env = {**os.environ, "COLUMNS": "160"}
    again = subprocess.run(cmd, capture_output=True, text=True, timeout=120, env=env)
    assert again.returncode == 0, again.stderr
    assert "capture, pooled share" in again.stdout and "caveat:" in again.stdout
    assert read_oracle_rows(out / "oracle.csv") == rows
    assert json.loads((out / "summary.json").read_text())["oracle"]["cost"]["swept_now"] == 0
