"""The campaign's figures (paper section 5), as PNG files drawn with matplotlib's Agg backend.

* ``replan_decision.png`` (paper Fig. "effect of replan decision"): one row per map; left, how
  often the slack method replanned; right, box plots of ``T_c^D = T_c^P - T_c^R`` split by
  whether it replanned.
* ``fleet_size.png`` (paper Fig. "effect of agents"): one panel per map, box plots of
  ``T_c^D`` per number of agents over the experiments where both methods replanned.
* ``oracle.png`` (``--oracle``): each policy's saving against the oracle's, and its replan time
  against the oracle's best one.

Box plots may leave out outliers (counted in the tick labels), see :func:`plot_all`.
"""

from __future__ import annotations

import math
import textwrap
from collections.abc import Callable, Sequence
from pathlib import Path

import matplotlib

matplotlib.use("Agg")  # before pyplot: files only, no display

import matplotlib.pyplot as plt
from matplotlib.axes import Axes
from matplotlib.figure import Figure
from matplotlib.ticker import MaxNLocator

from experiments.oracle_stats import Judged, policies_run, policy_replanned, policy_soc
from experiments.stats import Experiment, OutlierRules, map_order, outlier_reasons
from fleetgate.userio.files import atomic_open

REPLANNED_LABELS = ("Replan", "No Replan")


Hide = Callable[[Experiment], bool]


def _boxes(ax: Axes, groups: Sequence[Sequence[Experiment]], labels: Sequence[str],
           hide: Hide) -> None:
    """Box plots of ``T_c^D`` per group; experiments ``hide`` picks are counted, not drawn."""
    shown = [[e.difference_ms for e in g if not hide(e)] for g in groups]
    ticks = []
    for lab, g, values in zip(labels, groups, shown, strict=True):
        hidden = len(g) - len(values)
        ticks.append(f"{lab}\n(n={len(values)})" + (f"\n+{hidden} outl." if hidden else ""))
    ax.boxplot([v or [math.nan] for v in shown], showmeans=True, tick_labels=ticks)
    ax.axhline(0, color="grey", linewidth=0.8, linestyle="--")
    ax.yaxis.set_major_locator(MaxNLocator(integer=True))  # whole milliseconds


BOX_NOTE = ("boxes: quartiles and 1.5 IQR whiskers, line: median, triangle: mean; "
            "outliers by the summary's rules are not drawn")
NOTE_CHARS_PER_INCH = 15
"""Characters of the 7-point note per inch of figure width (with room to spare)."""
NOTE_LINE_INCH = 0.13


def _note_and_layout(fig: Figure) -> None:
    """Put :data:`BOX_NOTE` under the panels, wrapped to the figure's width, and lay the
    panels out above it (a narrow figure must not cut the note off)."""
    width, height = fig.get_size_inches()
    lines = textwrap.wrap(BOX_NOTE, int(width * NOTE_CHARS_PER_INCH))
    fig.text(0.5, 0.004, "\n".join(lines), ha="center", va="bottom", fontsize=7, color="grey")
    fig.tight_layout(rect=(0, (len(lines) * NOTE_LINE_INCH + 0.05) / height, 1, 1))


def replan_decision_figure(exps: Sequence[Experiment], maps_first: Sequence[str] = (),
                           hide: Hide = lambda e: False) -> Figure:
    """Per map: slack replanning frequency and the SOC difference, replanned vs not."""
    maps = map_order(exps, maps_first)
    fig, axes = plt.subplots(len(maps) or 1, 2, figsize=(9, 3.2 * max(1, len(maps))),
                             squeeze=False, gridspec_kw={"width_ratios": [1, 2]})
    for row, name in zip(axes, maps, strict=False):
        mine = [e for e in exps if e.map == name]
        yes = [e for e in mine if e.slack_replanned]
        no = [e for e in mine if not e.slack_replanned]
        row[0].bar(REPLANNED_LABELS, [len(yes), len(no)], color=["tab:blue", "tab:grey"])
        row[0].set_ylabel("experiments")
        row[0].yaxis.set_major_locator(MaxNLocator(integer=True))
        row[0].set_title(f"{name}: replanning frequency")
        _boxes(row[1], [yes, no], REPLANNED_LABELS, hide)
        row[1].set_ylabel("$T_c^P - T_c^R$ [ms]")
        row[1].set_title(f"{name}: SOC difference")
    _note_and_layout(fig)
    return fig


def fleet_size_figure(exps: Sequence[Experiment], maps_first: Sequence[str] = (),
                      hide: Hide = lambda e: False) -> Figure:
    """Per map: the SOC difference per number of agents where both methods replanned."""
    maps = map_order(exps, maps_first)
    cols = 2 if len(maps) > 1 else 1
    rows = max(1, math.ceil(len(maps) / cols))
    fig, axes = plt.subplots(rows, cols, figsize=(5.5 * cols, 3.4 * rows), squeeze=False)
    flat = [ax for line in axes for ax in line]
    for ax, name in zip(flat, maps, strict=False):
        mine = [e for e in exps if e.map == name and e.slack_replanned and e.random_replanned]
        counts = sorted({e.agents for e in exps if e.map == name})
        _boxes(ax, [[e for e in mine if e.agents == n] for n in counts],
               [str(n) for n in counts], hide)
        ax.set_xlabel("agents")
        ax.set_ylabel("$T_c^P - T_c^R$ [ms]")
        ax.set_title(f"{name}: both methods replanned")
    for ax in flat[len(maps):]:
        ax.set_visible(False)
    _note_and_layout(fig)
    return fig


def _save(fig: Figure, path: Path) -> Path:
    try:
        with atomic_open(path, "wb") as f:
            fig.savefig(f, format=path.suffix.lstrip(".") or "png", dpi=100)
    finally:
        plt.close(fig)
    return path


def plot_all(exps: Sequence[Experiment], folder: Path, maps_first: Sequence[str] = (),
             rules: OutlierRules | None = None) -> list[Path]:
    """Draw every figure into ``folder`` (maps ordered by :func:`map_order`); returns the files.

    With ``rules``, the experiments they flag as outliers are counted but not drawn (a replan
    whose solver hit its limit costs minutes of SOC and would flatten every other box).
    """
    folder.mkdir(parents=True, exist_ok=True)

    def hide(e: Experiment) -> bool:
        return rules is not None and bool(outlier_reasons(e, rules))

    return [_save(replan_decision_figure(exps, maps_first, hide),
                  folder / "replan_decision.png"),
            _save(fleet_size_figure(exps, maps_first, hide), folder / "fleet_size.png")]


def oracle_figure(judged: Sequence[Judged]) -> Figure:
    """Left: each policy's saving against the oracle's per experiment (capture = slope);
    right: each policy's replan time against the oracle's best replan time."""
    fig, (left, right) = plt.subplots(1, 2, figsize=(11, 4.6))
    top = max((j.oracle_saving for j in judged), default=1.0) or 1.0
    left.plot([0, top], [0, top], color="grey", linewidth=0.8, linestyle="--",
              label="the oracle's saving")
    left.axhline(0, color="grey", linewidth=0.8)
    times = [j.oracle.best_at_ms for j in judged if j.oracle.best_at_ms is not None]
    colours = {"random": "tab:orange", "slack": "tab:blue", "informed": "tab:green",
               "shadow": "tab:pink", "reschedule": "tab:purple", "reschedule+slack": "tab:red",
               "reschedule+informed": "tab:brown"}
    for policy in policies_run(judged):
        colour = colours[policy]
        left.scatter([j.oracle_saving for j in judged],
                     [j.exp.t_n - policy_soc(j.exp, policy) for j in judged], s=12,
                     color=colour, alpha=0.7, label=policy)
        pairs = [(j.oracle.best_at_ms, at) for j in judged
                 if j.oracle.best_at_ms is not None
                 and (at := policy_replanned(j.exp, policy)[1]) is not None]
        right.scatter([b for b, _ in pairs], [a for _, a in pairs], s=12, color=colour,
                      alpha=0.7, label=f"{policy} (n={len(pairs)})")
        times.extend(a for _, a in pairs)
    left.set_xlabel("oracle's saving $T_N - T_O$ [ms]")
    left.set_ylabel("policy's saving $T_N - T_X$ [ms]")
    left.set_title(f"saving per experiment (n={len(judged)})")
    left.legend(fontsize=8)
    end = max(times, default=1.0)
    right.plot([0, end], [0, end], color="grey", linewidth=0.8, linestyle="--",
               label="same time")
    right.set_xlabel("oracle's best replan time [ms]")
    right.set_ylabel("policy's replan time [ms]")
    right.set_title("when to replan: policy vs oracle")
    right.legend(fontsize=8)
    fig.tight_layout()
    return fig


def plot_oracle(judged: Sequence[Judged], folder: Path) -> Path:
    """Draw :func:`oracle_figure` into ``folder/oracle.png``."""
    folder.mkdir(parents=True, exist_ok=True)
    return _save(oracle_figure(judged), folder / "oracle.png")
