"""``fleetgate experiment``: the paper's evaluation campaign (section 5) in one command."""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict
from pathlib import Path
from typing import TYPE_CHECKING, Any

from fleetgate.userio.files import write_text
from gateway.execution.params import INTRUDER_READINGS
from gateway.execution.params import PAPER as PAPER_PARAMS
from gateway.planning.motion import MOTIONS
from gateway.runtime.exits import EXIT_OK, UsageError
from gateway.runtime.mapstore import MapNotFound, resolve
from sim_clients.stays import STAY_HELP, stay_option

if TYPE_CHECKING:
    from rich.table import Table

    from experiments.campaign import Blocks, SimSettings

JsonDict = dict[str, Any]


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    """Add ``fleetgate experiment``."""
    p = sub.add_parser(
        "experiment", help="run the paper's evaluation campaign (results.csv, summary, plots)",
        description="Run every (map, agents, instance, seed) experiment in its four variants "
        "(lower_bound, intruder, random, slack) in virtual time, in parallel and resumably; "
        "write OUT/results.csv, OUT/summary.json, OUT/*.png and print a table per map.")
    p.add_argument("--maps", nargs="+", metavar="MAP",
                   help="map names or files (with --paper: the subset of the paper's maps "
                   "lab, arena, room-32-32-4, random-32-32-20 to run)")
    p.add_argument("--agents", nargs="+", metavar="N[,N..]|MAP=N[,N..]",
                   help="agent counts for every map, or for one map as MAP=N,N")
    p.add_argument("--instances", type=int, help="instances per map and agent count "
                   "(--paper: the paper's)")
    p.add_argument("--seeds", type=int, help="seeds per instance (--paper: the paper's)")
    p.add_argument("--out", required=True, type=Path, help="output folder (reused to resume)")
    p.add_argument("--paper", action="store_true",
                   help="the paper's protocol: 13 map/agent groups x 20 instances x 5 seeds "
                   "= 1300 experiments x 4 variants")
    p.add_argument("--workers", type=int, default=os.cpu_count() or 1,
                   help="worker processes (default: the number of CPU cores)")
    p.add_argument("--scheduler", metavar="ADDRESS",
                   help="run on a Dask distributed cluster (e.g. tcp://127.0.0.1:8786)")
    p.add_argument("--solver-time", default="measured", metavar="measured|zero|MS",
                   help="how replanning time is charged in virtual time (default measured)")
    p.add_argument("--plan-time-limit", type=float, default=10.0, metavar="SEC",
                   help="an instance counts only if planned within this (default 10)")
    p.add_argument("--replan-time-limit", type=float, default=10.0, metavar="SEC",
                   help="limit of each replanning solve; past it the old plan is kept "
                   "(default 10)")
    p.add_argument("--threshold-ms", type=float, default=PAPER_PARAMS.threshold_ms,
                   help="slack threshold Δ̄T of the slack policy "
                   f"(default {PAPER_PARAMS.threshold_ms:g})")
    p.add_argument("--intruder-reading", choices=INTRUDER_READINGS, default="start",
                   help="the intruder takes the first cell its robot is estimated to START "
                   "moving into (default, the paper's 2 s are the intruder's time to get there "
                   "first) or to ARRIVE on, at or after T_a + 2 s")
    p.add_argument("--intruder-stay", metavar="SPEC|FILE", help=STAY_HELP)
    p.add_argument("--seed", type=int, default=0, help="seed of instance generation")
    p.add_argument("--motion", choices=MOTIONS, default="omni",
                   help="motion model of the plans (default omni); turning robots start "
                        "facing east")
    p.add_argument("--maps-dir", help="folder searched first for map names")
    p.add_argument("--limit", type=int, metavar="N",
                   help="stop after N new experiments (rerun to resume)")
    p.add_argument("--outlier-margin-ms", type=float, default=0.0,
                   help="outliers: 'better than no-replan / the lower bound' by more than this")
    p.add_argument("--outlier-similar-ms", type=float, default=100.0,
                   help="outliers: replan times this close count as 'a similar time'")
    p.add_argument("--outlier-diff-frac", type=float, default=0.10,
                   help="outliers: SOCs this far apart (fraction) count as 'different'")
    p.add_argument("--resamples", type=int, default=2000, help="bootstrap resamples")
    p.add_argument("--informed", action="store_true",
                   help="also run the 'informed' variant: replan when the slack policy does, "
                   "keeping robots off the cells the fleet reported blocked until each block's "
                   "estimated end (not the paper's)")
    p.add_argument("--shadow", action="store_true",
                   help="also run the 'shadow' variant: solve in the background while the fleet "
                   "moves (informed) and adopt a plan only when the estimate, the stop included, "
                   "says it pays (not the paper's)")
    p.add_argument("--block-history", type=_history, default="learned",
                   metavar="learned|none|MS[,MS..]",
                   help="what the block estimates of the informed, shadow and reschedule "
                   "variants start from. learned (default): the durations of the blocks the "
                   "fleet reported in the no-replan (intruder) runs of the experiments before "
                   "each one on the same map, in campaign order (--maps, --agents, instance, "
                   "seed; never its own or a later one's), the last --block-memory of them; "
                   "the first experiment of each map starts cold. none: every run starts cold. "
                   "MS,MS..: these durations, given, for every run")
    p.add_argument("--block-memory", type=int, default=LEARNED_BLOCKS, metavar="N",
                   help="--block-history learned: how many of the latest blocks are remembered "
                   f"(default {LEARNED_BLOCKS}, as the gateway across runs)")
    p.add_argument("--reschedule", action="store_true",
                   help="also run the 'reschedule' variant (switch Type 2 edges so others pass "
                   "a delayed robot, never replan) and 'reschedule+slack' (reschedule first, "
                   "replan when the slack policy does; with --informed also "
                   "'reschedule+informed'); not the paper's")
    p.add_argument("--oracle", action="store_true",
                   help="also sweep the oracle (one forced replan every --oracle-step-ms of each "
                   "run, the best kept) and report how much of its saving each policy captures "
                   "(OUT/oracle.csv, OUT/oracle.png)")
    p.add_argument("--clairvoyant", action="store_true",
                   help="also sweep the clairvoyant (one forced replan every --oracle-step-ms "
                   "from the intruder's appearance while it is there, each an informed solve "
                   "that knows its cell and true leave time; the best kept) and report each "
                   "policy's capture of its saving and per-experiment outcomes "
                   "(OUT/clairvoyant.csv)")
    p.add_argument("--oracle-sample", type=int, metavar="N",
                   help="sweep the oracle of N experiments drawn (seeded) from the campaign "
                   "instead of all of them")
    step = PAPER_PARAMS.oracle_step_ms
    p.add_argument("--oracle-step-ms", type=float, default=step, metavar="MS",
                   help=f"the oracle's step in virtual ms (default {step:g})")
    p.add_argument("--json", action="store_true",
                   help="print the summary as JSON instead of tables")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=run)


def _solver_time(text: str) -> str:
    from sim_clients.des import parse_solver_time

    try:
        parse_solver_time(text)
    except ValueError as exc:
        raise UsageError(f"--solver-time: {exc}") from None
    return text


LEARNED_BLOCKS = 100
"""The blocks a learned history remembers by default (the gateway keeps as many across
runs)."""


def _history(text: str) -> str | tuple[float, ...]:
    if text in ("learned", "none"):
        return text
    try:
        values = tuple(float(c) for c in text.split(",") if c)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not learned, none or a comma-separated list "
                                         "of ms") \
            from None
    if not all(0 < v < float("inf") for v in values):
        raise argparse.ArgumentTypeError(f"{text!r}: durations must be positive ms")
    return values


def _counts(text: str) -> list[int]:
    try:
        counts = [int(c) for c in text.split(",") if c]
    except ValueError:
        raise UsageError(f"--agents: {text!r} is not a comma-separated list of numbers") from None
    if not counts or min(counts) < 1:
        raise UsageError(f"--agents: {text!r} must list positive numbers")
    return counts


def parse_groups(maps: Sequence[str] | None, agents: Sequence[str] | None,
                 paper: bool) -> list[tuple[str, int]]:
    """The (map, agents) groups of the command line, in the order given.

    ``--agents`` items are counts for every map (``5,10 15``) or for one map (``arena=10,20``);
    a map's own counts replace the common ones. With ``--paper`` the defaults are the paper's.
    """
    from experiments.campaign import PAPER_GROUPS

    common: list[int] = []
    per_map: dict[str, list[int]] = {}
    for item in agents or ():
        if "=" in item:
            name, _, listed = item.partition("=")
            per_map.setdefault(name, []).extend(_counts(listed))
        else:
            common.extend(_counts(item))
    paper_maps = list(dict.fromkeys(m for m, _ in PAPER_GROUPS))
    names = list(maps) if maps else (paper_maps if paper else [])
    if not names:
        raise UsageError("--maps is required (or --paper)")
    unknown = sorted(set(per_map) - set(names))
    if unknown:
        raise UsageError(f"--agents names maps not in --maps: {', '.join(unknown)}")
    groups: list[tuple[str, int]] = []
    for name in names:
        counts = per_map.get(name) or common
        if not counts and paper:
            counts = [n for m, n in PAPER_GROUPS if m == name]
        if not counts:
            raise UsageError(f"no agent counts for map {name!r}: give --agents")
        groups.extend((name, n) for n in dict.fromkeys(counts))
    return groups


PROGRESS_LINE_S = 10.0
"""Off a terminal (a log, a pipe), a progress line at most this often (and at each phase's
end): rich's bar only draws on a terminal, and a campaign runs for minutes."""


class LineProgress:
    """Progress as plain lines on stderr: ``fleetgate experiment: experiments 300/1300, 45 s``."""

    def __init__(self, began: float, period_s: float = PROGRESS_LINE_S) -> None:
        self._began = began
        self._period_s = period_s
        self._last = began
        self._said: dict[str, int] = {}

    def update(self, phase: str, done: int, total: int) -> None:
        """Say where ``phase`` is if a period passed, or it just ended."""
        now = time.perf_counter()
        ended = done >= total and self._said.get(phase) != done
        if not ended and now - self._last < self._period_s:
            return
        self._last = now
        self._said[phase] = done
        print(f"fleetgate experiment: {phase} {done}/{total}, {now - self._began:.0f} s",
              file=sys.stderr, flush=True)


def _map_files(groups: Sequence[tuple[str, int]], maps_dir: str | None) -> dict[str, str]:
    """The file of each map, checked to be readable and to hold its largest fleet."""
    from gateway.planning.movingai import MapFormatError, read_map

    files = {}
    for name in dict.fromkeys(m for m, _ in groups):
        try:
            path = resolve(name, "map", maps_dir)
            free = sum(1 for _ in read_map(path).free_cells())
        except MapNotFound as exc:
            raise UsageError(str(exc)) from None
        except MapFormatError as exc:
            raise UsageError(str(exc)) from None
        except (OSError, UnicodeDecodeError) as exc:
            raise UsageError(f"cannot read the map {name}: {exc}") from None
        most = max(n for m, n in groups if m == name)
        if most > free:
            raise UsageError(f"--agents {most} on {name}: the map has only {free} free cells")
        files[name] = str(path.resolve())
    return files


def _short(name: str) -> str:
    return Path(name).stem if name.endswith(".map") else name


PAPER: dict[str, dict[str, str]] = {
    "lab": {"mp": "25.27", "mr": "3.45", "outliers": "0.7%"},
    "arena": {"mp": "27.55", "mr": "7.07", "outliers": "4.3%"},
    "room-32-32-4": {"mp": "27.70 (room32)", "mr": "10.92 (room32)"},
    "random-32-32-20": {"mp": "28.95", "mr": "9.81"},
    "all": {"share": "~1/3", "mp": "- (it gives the map mean)", "mr": "7.00 (see map mean)",
            "slack_ms": "80 / 8398 / ~90000", "random_ms": "20 / 1774 / -"},
}
"""The paper's reported numbers (section 5), shown next to ours."""


PAPER_MAP_MEANS = "27.37 / 7.81 (printed: 27.37 / 7.00)"
"""The paper's totals computed as ours are (the mean of its four per-map values): its slack
total 27.37 % is that mean, its random total 7.00 % is not (the mean of 3.45, 7.07, 10.92 and
9.81 is 7.81); both the recomputed and the printed values are shown."""


TABLE_WIDTH = 120
"""The tables' minimum width in columns (a pipe's default of 80 would cut cells)."""


def _mean_row(d: JsonDict, scale: float, fmt: str) -> tuple[str, str, str, str]:
    if d["mean"] is None:
        return "-", "-", "-", str(d["n"])
    lo, hi = d["ci95"]
    return (format(scale * d["mean"], fmt), f"[{scale * lo:{fmt}}, {scale * hi:{fmt}}]",
            format(scale * d["median"], fmt), str(d["n"]))


def _times(d: JsonDict) -> str:
    if d["n"] == 0:
        return "-"
    return f"{d['median']:.0f} / {d['mean']:.0f} / {d['max']:.0f}"


def summary_table(name: str, g: JsonDict, mean_of_maps: JsonDict | None = None) -> Table:
    """One map's (or all maps') numbers: value, 95 % bootstrap interval, n, the paper's value."""
    from rich.table import Table
    from rich.text import Text

    from experiments.campaign import EXTRA_VARIANTS

    class _PlainTable(Table):
        """A table whose cells are plain text (``[..]`` intervals are not rich markup)."""

        def add_row(self, *cells: Any, **kwargs: Any) -> None:
            super().add_row(*(Text(c) if isinstance(c, str) else c for c in cells), **kwargs)

    paper = PAPER.get(name, {})
    table = _PlainTable(title=f"{name}: {g['experiments']} experiments (replan ms: median / "
                        "mean / max)", title_justify="left")
    table.add_column("metric", no_wrap=True)
    for col in ("value", "95% CI", "median", "n"):
        table.add_column(col, justify="right", no_wrap=True)
    table.add_column("paper")
    share = g["slack_replan_share"]
    table.add_row("slack replanned", "-" if share is None else f"{100 * share:.1f}%", "", "",
                  str(g["slack_replanned"]), paper.get("share", ""))
    diff = g["soc_difference_ms"]
    table.add_row("T_P-T_R ms, replanned", *_mean_row(diff["replanned"], 1, "+.0f"),
                  "< 0" if paper else "")
    table.add_row("T_P-T_R ms, kept plan", *_mean_row(diff["not_replanned"], 1,
                                                                  "+.0f"), "~ 0" if paper else "")
    mit = g["mitigation"]
    table.add_row("M^P %, replanned",
                  *_mean_row(mit["slack_replanned"]["slack"], 100, ".2f"), paper.get("mp", ""))
    table.add_row("M^R %, replanned",
                  *_mean_row(mit["slack_replanned"]["random"], 100, ".2f"), paper.get("mr", ""))
    for extra in EXTRA_VARIANTS:
        if extra in mit["slack_replanned"]:
            table.add_row(f"M % ({extra}), slack replanned",
                          *_mean_row(mit["slack_replanned"][extra], 100, ".2f"), "")
    if mean_of_maps is not None:
        means = mean_of_maps["slack_replanned"]
        table.add_row("M^P/M^R %, map mean",
                      " / ".join("-" if means[k] is None else f"{100 * means[k]:.2f}"
                                 for k in ("slack", "random")), "", "", "",
                      PAPER_MAP_MEANS)
    table.add_row("M^P %, all", *_mean_row(mit["all"]["slack"], 100, ".2f"),
                  "~ 0 where kept" if paper else "")
    table.add_row("M^R %, all", *_mean_row(mit["all"]["random"], 100, ".2f"), "")
    times = g["solver_ms"]
    table.add_row("replan ms, slack", _times(times["slack"]), "", "",
                  str(times["slack"]["n"]), paper.get("slack_ms", ""))
    table.add_row("replan ms, random", _times(times["random"]), "", "",
                  str(times["random"]["n"]), paper.get("random_ms", ""))
    failed = g["replans_without_plan"]
    table.add_row("no plan in time", f"{failed['slack']} / {failed['random']}",
                  "slack / random", "", "", "")
    out = g["outliers"]
    rules = ", ".join(f"{k} {v}" for k, v in out["by_rule"].items() if v)
    table.add_row("outliers (not in M)",
                  "-" if out["share"] is None else f"{100 * out['share']:.1f}%",
                  rules, "", str(out["count"]), paper.get("outliers", ""))
    return table


def summary_tables(summary: JsonDict) -> list[Table]:
    """The printed tables: one per map, then all maps pooled."""
    tables = [summary_table(name, g) for name, g in summary["maps"].items()]
    if len(summary["maps"]) > 1:
        tables.append(summary_table("all", summary["all"], summary["mitigation_mean_of_maps"]))
    return tables


def _value_ci(d: JsonDict, scale: float = 100.0, fmt: str = ".1f", unit: str = "%") -> str:
    if d["value"] is None:
        return "-"
    ci = d["ci95"]
    interval = "" if ci is None else f" [{scale * ci[0]:{fmt}}, {scale * ci[1]:{fmt}}]"
    return f"{scale * d['value']:{fmt}}{unit}{interval}"


def _policy_table(title: str, policies: JsonDict,
                  rows: Sequence[tuple[str, Callable[[JsonDict], str]]]) -> Table:
    """A table with a column per policy and a row per ``(label, cell of a policy)``."""
    from rich.table import Table
    from rich.text import Text

    table = Table(title=title, title_justify="left")
    table.add_column("statistic", no_wrap=True)
    for name in policies:
        table.add_column(name, justify="right", no_wrap=True)
    for label, cell in rows:
        table.add_row(Text(label), *(Text(cell(p)) for p in policies.values()))
    return table


def _ci_of(key: str) -> Callable[[JsonDict], str]:
    return lambda p: _value_ci(p[key])


def oracle_table(o: JsonDict) -> Table:
    """Each policy against the oracle: one row per statistic, 95 % intervals."""
    rows: list[tuple[str, Callable[[JsonDict], str]]] = [
        (label, _ci_of(key)) for key, label in (
            ("capture", "capture, pooled share of the oracle's saving"),
            ("capture_median", "capture, median per experiment"),
            ("worse_than_none", "worse than not replanning"),
            ("replanned", "replanned"),
            ("mitigation", "mitigation where it replanned"),
            ("oracle_mitigation", "  the oracle's, same experiments"))]
    rows.append(("replan time - oracle's best, median ms",
                 lambda p: "-" if (d := p["trigger_minus_best_ms"])["median"] is None
                 else f"{d['median']:+.0f} (n={d['n']})"))
    return _policy_table(f"oracle: {o['experiments']} experiments, one forced replan every "
                         f"{o['step_ms']:g} ms; value [95% interval]", o["policies"], rows)


def clairvoyant_table(c: JsonDict) -> Table:
    """Each policy against the clairvoyant, and its per-experiment outcomes."""
    me = c["clairvoyant"]

    def upper(p: JsonDict) -> str:
        u = p["worse_than_none"]["upper95"]
        return "-" if u is None else f"{100 * u:.1f}%"

    def cost(p: JsonDict) -> str:
        w = p["worse_than_none"]["cost"]
        return "-" if not w["n"] else f"{w['median_ms']:.0f} / {w['max_ms']:.0f}"

    return _policy_table(
        f"clairvoyant: {c['experiments']} experiments; it saves in {_value_ci(me['saves'])} of "
        f"them, {me['saving_ms']['value'] or 0:.0f} ms on average; value [95% interval]",
        c["policies"],
        [("capture, pooled share of its saving", _ci_of("capture")),
         ("capture, median per experiment", _ci_of("capture_median")),
         ("worse than not replanning", _ci_of("worse_than_none")),
         ("  upper 95% bound (Clopper-Pearson)", upper),
         ("  cost when worse, median / max ms", cost),
         ("saving, mean ms", lambda p: _value_ci(p["saving_ms"], 1.0, ".0f", ""))])


def oracle_line(o: JsonDict) -> str:
    """The oracle's own numbers."""
    me = o["oracle"]
    lead = me["best_at_minus_appear_ms"]["median"]
    return (f"oracle: saves in {_value_ci(me['saves'])} of experiments; mitigation "
            f"{_value_ci(me['mitigation'])} over all experiments with an intruder influence "
            f"(with replans from T_a on only: {_value_ci(me['mitigation_after_appear'])}); "
            f"its best replan is at T_a{'' if lead is None else f'{lead:+.0f}'} ms (median)")


def oracle_cost_line(cost: JsonDict, workers_hint: int) -> str:
    """What the sweep cost and what the whole paper campaign's would."""
    full = cost["full_campaign_cpu_s_estimate"]
    missing = cost["groups_not_sampled"]
    line = (f"oracle sweep: {cost['replans']} forced replans, {cost['solves']} solves, "
            f"{cost['continuations']} continuations simulated; {cost['cpu_s_total']:.1f} CPU s "
            f"in all ({cost['swept_now']} swept in this run, {cost['running_s']:.1f} s wall)")
    if missing:
        line += ("; no estimate for the paper's 1300 experiments: no sample of "
                 + ", ".join(missing))
    elif full is not None:
        line += (f"; the paper's 1300 experiments would take about {full / 60:.0f} CPU min, "
                 f"{full / 60 / max(1, workers_hint):.0f} min on {workers_hint} cores "
                 "(from this sample's mean CPU per map and fleet size)")
    return line


def history_statement(sim: SimSettings, blocks: dict[Any, Blocks]) -> str:
    """What the block estimates of the history variants started from, in words (the
    summary's ``campaign.block_history``)."""
    if sim.block_history_ms:
        return ("given: every informed, shadow and reschedule run starts with the block "
                "durations " + ", ".join(f"{d:g}" for d in sim.block_history_ms) + " ms "
                "(typed on the command line, not learned)")
    if not sim.learned_blocks:
        return "none: every run starts cold (no earlier block known)"
    durations = sorted(d for b in blocks.values() for d in b.durations_ms)
    seen = (f"; the intruder runs reported {len(durations)} blocks in "
            f"{sum(1 for b in blocks.values() if b.durations_ms)} of {len(blocks)} experiments"
            + (f", median {durations[len(durations) // 2]:.0f} ms" if durations else ""))
    return ("learned: each experiment's informed, shadow and reschedule runs start with the "
            f"last {sim.learned_blocks} durations of the blocks the fleet reported (its "
            "block tracker, from the robots' blocked reports to the cell being free; not the "
            "simulator's ground truth) in the no-replan (intruder) runs of the experiments "
            "before it on the same map, in campaign order; never its own or a later "
            "experiment's; the first experiment of each map starts cold" + seen)


def run(args: argparse.Namespace) -> int:
    """Run (or resume) the campaign, then write the summary and plots and print the tables."""
    from rich.console import Console
    from rich.progress import (
        BarColumn,
        MofNCompleteColumn,
        Progress,
        TextColumn,
        TimeElapsedColumn,
    )

    from experiments.campaign import (
        HISTORY_VARIANTS,
        PAPER_GROUPS,
        PAPER_INSTANCES,
        PAPER_SEEDS,
        CampaignError,
        CampaignSpec,
        SimSettings,
        open_executor,
        run_campaign,
    )
    from experiments.clairvoyant_stats import summarize_clairvoyant
    from experiments.oracle import run_oracle
    from experiments.oracle_stats import extrapolate_cpu_s, judge, summarize_oracle
    from experiments.plots import plot_all, plot_oracle
    from experiments.stats import OutlierRules, join_experiments, summarize

    groups = parse_groups(args.maps, args.agents, args.paper)
    if args.workers < 1:
        raise UsageError(f"--workers must be positive, got {args.workers}")
    if args.threshold_ms < 0 or args.replan_time_limit <= 0:
        raise UsageError("--threshold-ms must be >= 0 and --replan-time-limit > 0")
    if not args.oracle_step_ms > 0:
        raise UsageError(f"--oracle-step-ms must be positive, got {args.oracle_step_ms:g}")
    if args.oracle_sample is not None and args.oracle_sample < 1:
        raise UsageError(f"--oracle-sample must be positive, got {args.oracle_sample}")
    if args.oracle_sample is not None and not (args.oracle or args.clairvoyant):
        raise UsageError("--oracle-sample needs --oracle or --clairvoyant")
    if args.block_memory < 1:
        raise UsageError(f"--block-memory must be positive, got {args.block_memory}")
    history = args.block_history
    stay = stay_option(args.intruder_stay)
    sim = SimSettings(solver_time=_solver_time(args.solver_time), threshold_ms=args.threshold_ms,
                      replan_time_limit_s=args.replan_time_limit,
                      intruder_reading=args.intruder_reading,
                      intruder_stay=None if stay is None else stay.text,
                      block_history_ms=history if isinstance(history, tuple) else (),
                      learned_blocks=args.block_memory if history == "learned" else 0)
    files = _map_files(groups, args.maps_dir)
    named = [(_short(m), n) for m, n in groups]
    stems = {_short(m) for m in files}
    if len(stems) != len(files):
        raise UsageError("two --maps have the same name; rename one of the files")
    try:
        spec = CampaignSpec(
            groups=tuple(named),
            instances=args.instances or (PAPER_INSTANCES if args.paper else 0),
            seeds=args.seeds or (PAPER_SEEDS if args.paper else 0),
            seed=args.seed, plan_time_limit_s=args.plan_time_limit, sim=sim,
            motion=args.motion,
            extra_variants=tuple(v for v in ("informed", "shadow") if getattr(args, v))
            + (("reschedule", "reschedule+slack") if args.reschedule else ())
            + (("reschedule+informed",) if args.reschedule and args.informed else ()))
        rules = OutlierRules(args.outlier_margin_ms, args.outlier_similar_ms,
                             args.outlier_diff_frac)
    except (CampaignError, TypeError) as exc:
        raise UsageError(str(exc)) from None
    map_paths = {_short(m): f for m, f in files.items()}
    console = Console(stderr=True)
    began = time.perf_counter()
    with Progress(TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(),
                  TimeElapsedColumn(), console=console, disable=args.no_progress) as bar:
        phases = ("instances", "experiments", *(("oracle",) if args.oracle else ()),
                  *(("clairvoyant",) if args.clairvoyant else ()))
        ids = {phase: bar.add_task(phase, total=None) for phase in phases}

        lines = LineProgress(began) if not (args.no_progress or console.is_terminal) else None

        def progress(phase: str, done: int, total: int) -> None:
            bar.update(ids[phase], completed=done, total=total)
            if lines is not None:
                lines.update(phase, done, total)

        try:
            with open_executor(args.workers, args.scheduler) as (executor, workers):
                result = run_campaign(spec, args.out, map_paths, executor=executor,
                                      workers=workers, limit=args.limit,
                                      progress=progress)
                oracle = None if not args.oracle else run_oracle(
                    spec, args.out, map_paths, result.records, executor=executor,
                    workers=workers, step_ms=args.oracle_step_ms, sample=args.oracle_sample,
                    progress=progress)
                clair = None if not args.clairvoyant else run_oracle(
                    spec, args.out, map_paths, result.records, executor=executor,
                    workers=workers, step_ms=args.oracle_step_ms, sample=args.oracle_sample,
                    progress=progress, clairvoyant=True)
        except CampaignError as exc:
            raise UsageError(str(exc)) from None
    wall = time.perf_counter() - began
    order = [m for m, _ in spec.groups]
    summary = summarize(result.rows, rules, seed=args.seed, resamples=args.resamples,
                        maps_first=order)
    summary["campaign"] = {"complete": result.complete, "instances_planned": result.planned,
                           "experiments_run": result.ran, "wall_s": round(wall, 3),
                           "planning_s": result.planning_s, "running_s": result.running_s,
                           "failures": [asdict(f) for f in result.failures],
                           **spec.settings(),
                           "block_history": history_statement(spec.sim, result.blocks)}
    exps, _ = join_experiments(result.rows)
    pictures = plot_all(exps, args.out, order, rules)
    if oracle is not None:
        summary["oracle"] = summarize_oracle(exps, oracle.rows, appear_ms=sim.intruder_appear_ms,
                                             seed=args.seed, resamples=args.resamples)
        summary["oracle"]["cost"].update(
            running_s=oracle.running_s, swept_now=oracle.ran,
            failures=[asdict(f) for f in oracle.failures],
            full_campaign_cpu_s_estimate=extrapolate_cpu_s(
                oracle.rows, PAPER_GROUPS, PAPER_INSTANCES * PAPER_SEEDS),
            groups_not_sampled=[f"{m}/{n}" for m, n in PAPER_GROUPS
                                if not any((r.map, r.agents) == (m, n) for r in oracle.rows)])
        pictures.append(plot_oracle(judge(exps, oracle.rows), args.out))
    if clair is not None:
        summary["clairvoyant"] = summarize_clairvoyant(
            exps, clair.rows, [] if oracle is None else oracle.rows, seed=args.seed,
            resamples=args.resamples)
        summary["clairvoyant"]["cost"] = {
            "cpu_s_total": round(sum(r.cpu_s for r in clair.rows), 3),
            "running_s": clair.running_s, "swept_now": clair.ran,
            "failures": [asdict(f) for f in clair.failures]}
    write_text(args.out / "summary.json", json.dumps(summary, indent=2) + "\n")
    class Out(Console):
        def on_broken_pipe(self) -> None:
            raise BrokenPipeError  # rich would exit 1; every command ends with 141 here

    out = Out()
    out.width = max(out.width, TABLE_WIDTH)  # never truncate numbers on a narrow terminal
    if args.json:
        print(json.dumps(summary, indent=2))
        return EXIT_OK
    for table in summary_tables(summary):
        out.print(table)
    if len(summary["maps"]) > 1:
        out.print(f"paper totals: {summary['paper_totals']['finding']}", highlight=False)
    if set(spec.variants) & HISTORY_VARIANTS:
        out.print(f"block history: {summary['campaign']['block_history']}", highlight=False)
    if oracle is not None:
        out.print(oracle_table(summary["oracle"]))
        out.print(oracle_line(summary["oracle"]), highlight=False)
        for caveat in summary["oracle"]["caveats"]:
            out.print(f"caveat: {caveat}", highlight=False)
        cost = summary["oracle"]["cost"]
        out.print(oracle_cost_line(cost, workers_hint=args.workers), highlight=False)
    if clair is not None:
        out.print(clairvoyant_table(summary["clairvoyant"]))
    state = "complete" if result.complete else "INCOMPLETE (rerun the same command to resume)"
    if result.failures:
        state += (f"; {len(result.failures)} simulations FAILED (see "
                  f"{args.out / 'failures.jsonl'})")
    out.print(f"{len(exps)} experiments, {state}; planned {result.planned} instances in "
              f"{result.planning_s:.1f} s and ran {result.ran} experiments in "
              f"{result.running_s:.1f} s ({wall:.1f} s in all); wrote "
              f"{args.out / 'results.csv'}, "
              f"{args.out / 'summary.json'}, " + ", ".join(str(p) for p in pictures))
    return EXIT_OK
