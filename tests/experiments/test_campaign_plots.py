"""The campaign figures are written for hand-made experiments, outliers and empty groups too."""

from __future__ import annotations

from pathlib import Path

import matplotlib.pyplot as plt
from matplotlib.figure import Figure

from experiments.plots import fleet_size_figure, plot_all, replan_decision_figure
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


def _inside_figure_and_integer_ticks(fig: Figure) -> None:
    fig.canvas.draw()
    page = fig.bbox
    for text in fig.texts:
        box = text.get_window_extent()
        assert page.x0 <= box.x0 and box.x1 <= page.x1 and page.y0 <= box.y0, text.get_text()
    for ax in fig.axes:
        if ax.get_visible():
            ticks = [t for t in ax.get_yticks() if ax.get_ylim()[0] <= t <= ax.get_ylim()[1]]
            assert ticks and all(float(t).is_integer() for t in ticks), (ax.get_title(), ticks)


def test_one_narrow_map_keeps_its_note_and_whole_ticks() -> None:
    # the quick campaign: one map, few experiments, SOC differences of a few ms
    exps = [_exp("lab", 5, 0, 13001, slack=True), _exp("lab", 5, 1, 13002, slack=True),
            _exp("lab", 10, 0, 13000, slack=False)]
    for figure in (fleet_size_figure(exps, ["lab"]), replan_decision_figure(exps, ["lab"])):
        _inside_figure_and_integer_ticks(figure)
        plt.close(figure)
