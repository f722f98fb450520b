"""Campaigns: reproducible, resumable, the same on a process pool and a Dask cluster; the CLI.

Runs real worker processes on a tiny campaign (lab, 5 agents, 2 instances x 2 seeds) with the
solver's time charged as zero, so every row is a function of the seed.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from experiments.campaign import (
    COLUMNS,
    VARIANTS,
    CampaignError,
    CampaignSpec,
    ExperimentTask,
    InstanceRecord,
    SimSettings,
    open_executor,
    read_results,
    run_campaign,
    run_experiment,
)
from experiments.plots import plot_all
from experiments.stats import join_experiments
from gateway.runtime.mapstore import resolve

SPEC = CampaignSpec(groups=(("lab", 5),), instances=2, seeds=2,
                    sim=SimSettings(solver_time="zero"), plan_time_limit_s=20)
MAPS = {"lab": str(resolve("lab", "map"))}


def _run(out: Path, spec: CampaignSpec = SPEC, limit: int | None = None,
         workers: int = 2) -> tuple[int, int, bool]:
    with open_executor(workers) as (pool, n):
        res = run_campaign(spec, out, MAPS, executor=pool, workers=n, limit=limit)
    return res.planned, res.ran, res.complete


@pytest.fixture(scope="module")
def full(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("full")
    assert _run(out) == (2, 4, True)
    return out


def test_rows_are_complete_and_the_lower_bound_is_the_plan(full: Path) -> None:
    text = (full / "results.csv").read_text()
    assert text.splitlines()[0] == ",".join(COLUMNS)
    rows = read_results(full / "results.csv")
    assert [(r.instance, r.seed, r.variant) for r in rows] == [
        (i, s, v) for i in range(2) for s in sorted(SPEC.experiment_seeds("lab", 5, i))
        for v in VARIANTS]
    for r in rows:
        inst = json.loads((full / "instances" / f"lab-5-{r.instance:03d}.json").read_text())
        assert len(inst["agents"]) == 5
        if r.variant == "lower_bound":
            # No intruder, every action 1000 ms: execution is exactly the plan.
            assert (r.soc_ms, r.makespan_ms) == (inst["soc"] * 1000, inst["makespan"] * 1000)
        if r.variant in ("lower_bound", "intruder"):
            assert not r.replanned and r.replan_at_ms is None
        if r.replanned:
            assert r.replan_at_ms is not None and r.replan_at_ms >= 3000  # not before T_a
        assert r.solver_ms == 0  # --solver-time zero


def test_same_seed_same_rows_and_rerun_skips_everything(full: Path, tmp_path: Path) -> None:
    assert _run(tmp_path) == (2, 4, True)
    assert (tmp_path / "results.csv").read_text() == (full / "results.csv").read_text()
    for f in (full / "instances").iterdir():
        mine, theirs = (json.loads(p.read_text()) for p in (tmp_path / "instances" / f.name, f))
        del mine["runtime_s"], theirs["runtime_s"]  # wall time
        assert mine == theirs
    # Everything is there already: nothing is planned or run again.
    assert _run(tmp_path) == (0, 0, True)
    assert (tmp_path / "results.csv").read_text() == (full / "results.csv").read_text()


def test_interrupted_then_resumed_equals_uninterrupted(full: Path, tmp_path: Path) -> None:
    assert _run(tmp_path, limit=1, workers=1) == (2, 1, False)
    assert len(read_results(tmp_path / "results.csv")) == len(VARIANTS)
    # A kill in the middle of a write leaves half a line: it is dropped and redone.
    with (tmp_path / "results.csv").open("a") as f:
        f.write("lab,5,1,7,slack,123")
    assert _run(tmp_path) == (0, 3, True)
    assert (tmp_path / "results.csv").read_text() == (full / "results.csv").read_text()


def test_dask_local_cluster_gives_the_same_rows(full: Path, tmp_path: Path) -> None:
    distributed = pytest.importorskip("distributed")
    with (distributed.LocalCluster(n_workers=1, threads_per_worker=2, processes=False,
                                   dashboard_address=None) as cluster,
          open_executor(scheduler=cluster.scheduler_address) as (ex, n)):
        assert n == 2
        res = run_campaign(SPEC, tmp_path, MAPS, executor=ex, workers=n)
    assert (res.planned, res.ran, res.complete) == (2, 4, True)
    assert (tmp_path / "results.csv").read_text() == (full / "results.csv").read_text()


def test_other_settings_refuse_the_folder(full: Path, tmp_path: Path) -> None:
    other = CampaignSpec(groups=SPEC.groups, instances=2, seeds=2, seed=1,
                         sim=SimSettings(solver_time="zero"), plan_time_limit_s=20)
    (tmp_path / "results.csv").write_text((full / "results.csv").read_text())
    (tmp_path / "campaign.json").write_text((full / "campaign.json").read_text())
    with pytest.raises(CampaignError, match="seed: 0 there, 1 now"):
        _run(tmp_path, other)
    (tmp_path / "results.csv").write_text("map,agents\n")
    with pytest.raises(CampaignError, match="unexpected header"):
        _run(tmp_path)


def test_plots_are_written(full: Path, tmp_path: Path) -> None:
    exps, incomplete = join_experiments(read_results(full / "results.csv"))
    assert (len(exps), incomplete) == (4, 0)
    for path in plot_all(exps, tmp_path):
        assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
        assert path.stat().st_size > 5000


def test_cli_writes_results_summary_and_plots(full: Path, tmp_path: Path) -> None:
    out = tmp_path / "cli"
    # The console script, as a user runs it.
    cmd = [str(Path(sys.executable).with_name("fleetgate")), "experiment", "--maps", "lab",
           "--agents", "5", "--instances", "2", "--seeds", "2", "--solver-time", "zero",
           "--plan-time-limit", "20", "--out", str(out), "--workers", "2", "--no-progress"]
    env = {**os.environ, "COLUMNS": "160"}  # rich wraps tables to the terminal's width
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=120, env=env)
    assert done.returncode == 0, done.stderr
    assert (out / "results.csv").read_text() == (full / "results.csv").read_text()
    summary = json.loads((out / "summary.json").read_text())
    assert summary["all"]["experiments"] == 4 and summary["campaign"]["complete"]
    assert list(summary["maps"]) == ["lab"]
    assert "lab: 4 experiments" in done.stdout and "M^P %, replanned" in done.stdout
    for name in ("replan_decision.png", "fleet_size.png"):
        assert (out / name).stat().st_size > 5000

    at = cmd.index("--agents") + 1
    bad = subprocess.run([*cmd[:at], "x,5", *cmd[at + 1:]], capture_output=True, text=True,
                         timeout=60)
    assert bad.returncode == 2
    assert "--agents" in bad.stderr and len(bad.stderr.strip().splitlines()) == 1


def test_a_simulation_that_raises_is_a_failure_not_a_crash(full: Path) -> None:
    rec = InstanceRecord.from_json(json.loads((full / "instances" / "lab-5-000.json").read_text()))
    task = ExperimentTask(MAPS["lab"], rec, 3, ("lower_bound", "slack"),
                          SimSettings(solver_time="zero", threshold_ms=-1))
    rows, failures, blocks = run_experiment(task)
    assert rows == [] and blocks is None
    assert [(f.instance, f.seed, f.variant) for f in failures] == [(0, 3, "lower_bound"),
                                                                   (0, 3, "slack")]
    assert all("threshold_ms" in f.error for f in failures)


def test_a_turning_campaign_plans_turns_and_resumes(tmp_path: Path) -> None:
    spec = CampaignSpec(groups=(("lab", 4),), instances=1, seeds=1, motion="turning",
                        sim=SimSettings(solver_time="zero"), plan_time_limit_s=20)
    assert _run(tmp_path, spec, workers=1) == (1, 1, True)
    data = json.loads((tmp_path / "instances" / "lab-4-000.json").read_text())
    assert data["motion"] == "turning"
    assert all(len(c) == 3 and c[2] in range(4) for a in data["agents"] for c in a["path"])
    assert all(a["path"][0][2] == 0 for a in data["agents"])  # every robot starts facing east
    record = InstanceRecord.from_json(data)
    assert record.plan.headings is not None and record.to_json(spec.seed) == data
    rows = read_results(tmp_path / "results.csv")
    lower = next(r for r in rows if r.variant == "lower_bound")
    assert (lower.soc_ms, lower.makespan_ms) == (data["soc"] * 1000, data["makespan"] * 1000)
    assert _run(tmp_path, spec, workers=1) == (0, 0, True)  # resumed: nothing left to do
    with pytest.raises(CampaignError, match="motion: 'turning' there, 'omni' now"):
        _run(tmp_path, CampaignSpec(groups=spec.groups, instances=1, seeds=1,
                                    sim=SimSettings(solver_time="zero"), plan_time_limit_s=20))
