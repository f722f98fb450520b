"""The campaign figures are written for hand-made experiments, outliers and empty groups too."""

from __future__ import annotations

from pathlib import Path

from experiments.plots import plot_all
from experiments.stats import Experiment, OutlierRules, outlier_reasons

PNG = b"\x89PNG\r\n\x1a\n"


def _exp(map_: str, agents: int, instance: int, t_p: float, *, slack: bool,
         solved: bool = True) -> Experiment:
    return Experiment(map_, agents, instance, 0, t_lb=10000, t_n=14000, t_r=13000, t_p=t_p,
                      slack_replanned=slack, random_replanned=True,
                      slack_at_ms=5000 if slack else None, random_at_ms=8000,
                      slack_solver_ms=10 if slack else 0, random_solver_ms=10,
                      slack_solved=solved)


def test_figures_with_an_outlier_and_an_empty_group(tmp_path: Path) -> None:
    exps = [_exp("lab", 5, 0, 11000, slack=True), _exp("lab", 5, 1, 14000, slack=False),
            _exp("lab", 10, 0, 300000, slack=True, solved=False),   # solver hit its limit
            _exp("arena", 10, 0, 12000, slack=False)]               # arena: nobody replanned
    assert outlier_reasons(exps[2], OutlierRules()) == ("replan_without_plan",)
    for rules in (None, OutlierRules()):
        out = tmp_path / ("rules" if rules else "all")
        files = plot_all(exps, out, ["lab", "arena"], rules)
        assert [f.name for f in files] == ["replan_decision.png", "fleet_size.png"]
        for f in files:
            assert f.read_bytes()[:8] == PNG and f.stat().st_size > 5000
