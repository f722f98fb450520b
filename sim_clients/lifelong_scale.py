"""The competition's large instances under the 2026 rules (``bench/lifelong.py --scale``).

LoRR 2024 main-round instances warehouse_large (10,000 agents, WAREHOUSE.json) and brc202d
(6,500 agents, GAME.json), read from a copy of the public MAPF-Competition/Benchmark-Archive
repository (``--archive DIR`` or ``$FLEETGATE_LORR_ARCHIVE``; never committed here; skipped
cleanly when absent), converted by :mod:`gateway.planning.lorr_convert` (3 ticks an action,
delays, no following) and run for ``--ticks`` ticks, each in its own process, with a
station cap (:data:`STATION_CAP`): planner CPU per call (p50, p99, max and the calls over
the 1 s period, over every call, the first included; the first call's apart too) and of the
tables of the robots' later errands computed between calls (on the second core, as the
gateway's planner worker does: not charged to the calls), peak RSS of the run and of the
independent validator (``tracecheck/lorr.py``) after it, tasks finished and first errands
done, the shares of robot-ticks spent delayed, waiting for another robot and without
committed work, and the ratio to the published winners' figures over 5,000 steps (WPPL,
2023; EPIBT, 2024) scaled to the same number of ticks and to the same number of actions (a
2026 tick is a third of an action: see the module doc of the converter).
:data:`MILLION` adds a generated 10,000-robot warehouse of 1,000,000 cells (no archive
needed, no published figures).
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
import resource
import subprocess
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from gateway.planning.generators import warehouse_map
from gateway.planning.lorr import LorrProblem
from gateway.planning.lorr_convert import AGENT_COUNTER_2026, DELAY_2026, REVEAL_2026, convert
from gateway.planning.movingai import format_map
from sim_clients.lifelong import LifelongConfig, lorr_output, run_lifelong
from tracecheck.lorr import check_output, read_free

ARCHIVE_ENV = "FLEETGATE_LORR_ARCHIVE"
STATION_CAP = 4
"""Robots sent to one first-errand cell at a time in the scale runs
(:attr:`~gateway.execution.lifelong.tasks.TaskPool.station_cap`; 600 ticks, warehouse_large:
137 tasks without a cap, 591 with 12, 1,075 with 4; with its corridor lanes, one run each:
1,309 without, 1,377 with 4, 1,461 with 12, 1,394 with 24, within the runs' spread)."""
PUBLISHED_STEPS = 5000
"""Steps of the competitions' main-round runs of these instances."""


@dataclass(frozen=True)
class ScaleInstance:
    """An instance of the archive and the winners' published tasks finished on it."""

    path: str
    wppl: int
    """LoRR 2023 winner (on the 2023 instance of the same map and team size)."""
    epibt: int
    """LoRR 2024 winner."""


MAIN_2024 = "2024 Competition/Main Round Evaluation Instances"
INSTANCES = {
    "warehouse_large": ScaleInstance(f"{MAIN_2024}/warehouse.domain/WAREHOUSE.json",
                                     193_959, 154_834),
    "brc202d": ScaleInstance(f"{MAIN_2024}/game.domain/GAME.json", 28_946, 23_274),
}


MILLION = "warehouse_1m"
"""A generated instance (no archive needed): :func:`million_warehouse`."""


def million_warehouse(robots: int = 10_000, seed: int = 0) -> LorrProblem:
    """10,000 robots on a generated 1000 x 1000 warehouse (1,000,000 cells, 586,660 free):
    shelf blocks of 10 x 2 cells with aisles of 2, like warehouse_large at 14 times its area.
    As in warehouse_large (353 emitter cells on its edges, 11,118 shelf cells), a task fetches
    from one of 500 stations on the outer ring (every 8th cell) to a random cell beside a
    shelf; ``4 * robots`` tasks, robots on random free cells, under the 2026 rules of
    :mod:`gateway.planning.lorr_convert` (3 ticks an action, its delays, reveal 1.5)."""
    grid = warehouse_map(83, 249, 10, shelf_depth=2, aisle=2, border=3,
                         name="warehouse-1000-1000")
    free = grid.free
    ring = np.zeros_like(free)
    ring[[0, -1], :] = True
    ring[:, [0, -1]] = True
    stations = np.flatnonzero((ring & free).ravel())[::8]
    near = np.zeros_like(free)
    near[1:, :] |= ~free[:-1, :]
    near[:-1, :] |= ~free[1:, :]
    shelves = np.flatnonzero((near & free).ravel())
    rng = np.random.default_rng(seed)
    starts = rng.choice(np.flatnonzero(free.ravel()), size=robots, replace=False)
    tasks = zip(rng.choice(stations, size=4 * robots), rng.choice(shelves, size=4 * robots),
                strict=True)
    return LorrProblem(grid=grid, starts=tuple(int(c) for c in starts),
                       tasks=tuple((int(a), int(b)) for a, b in tasks),
                       num_tasks_reveal=REVEAL_2026, agent_counter=AGENT_COUNTER_2026,
                       delay=dataclasses.replace(DELAY_2026, seed=seed), name=grid.name)


def archive_dir(given: Path | None) -> Path:
    """The archive copy to read: ``given``, else ``$FLEETGATE_LORR_ARCHIVE``, else
    ``~/.cache/fleetgate/lorr-archive``."""
    if given is not None:
        return given
    env = os.environ.get(ARCHIVE_ENV)
    return Path(env) if env else Path.home() / ".cache" / "fleetgate" / "lorr-archive"


def _peak_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def _percentile(values: list[float], q: float) -> float:
    """The nearest-rank ``q`` percentile (0 for none)."""
    ordered = sorted(values)
    return ordered[max(0, math.ceil(q * len(ordered)) - 1)] if ordered else 0.0


def scale_one(name: str, archive: Path, ticks: int, reassign: int,
              station_cap: int | None = STATION_CAP) -> dict[str, Any]:
    """Run one instance in this process (see the module doc; ``station_cap``: the task
    pool's, :attr:`~gateway.execution.lifelong.tasks.TaskPool.station_cap`); one dict of
    figures."""
    changes: tuple[str, ...] = ("generated under the 2026 rules",)
    if name == MILLION:
        prob = million_warehouse()
    else:
        conv = convert(archive / INSTANCES[name].path)
        prob, changes = conv.problem, conv.changes
    cfg = LifelongConfig(prob, ticks=ticks, reassign=reassign, station_cap=station_cap)
    res = run_lifelong(cfg)
    run_mb = _peak_mb()
    check_output(lorr_output(cfg, res), read_free(format_map(prob.grid)))
    times = res.planner_times
    actions = ticks / prob.agent_counter
    out: dict[str, Any] = {
        "instance": name, "robots": prob.team_size, "ticks": ticks, "reassign": reassign,
        "station_cap": station_cap,
        "free_cells": int(prob.grid.free.sum()), "finished": res.finished,
        "calls": res.calls, "preprocess_s": round(res.extra["preprocess_s"], 2),
        "first_call_s": round(times[0], 2) if times else None,
        "cpu_p50_s": round(_percentile(times, 0.5), 3),
        "cpu_p99_s": round(_percentile(times, 0.99), 3),
        "cpu_max_s": round(max(times, default=0.0), 3),
        "calls_over_1s": sum(t > 1.0 for t in times),
        "warm_p99_s": round(_percentile(res.warm_times[1:], 0.99), 3),
        "warm_max_s": round(max(res.warm_times[1:], default=0.0), 3),
        "peak_rss_mb": round(run_mb), "validator_peak_rss_mb": round(_peak_mb()),
        "idle": {k: round(res.extra[k], 3) for k in ("delayed", "waiting", "no_work")},
        "first_errands_done": sum(e[3] == 1 for e in res.events),
        "valid": True, "changes": list(changes),
    }
    if name == MILLION:
        return out
    inst = INSTANCES[name]
    for who, figure in (("wppl", inst.wppl), ("epibt", inst.epibt)):
        out[f"{who}_per_tick_ratio"] = round(res.finished / (figure * ticks / PUBLISHED_STEPS),
                                             3)
        out[f"{who}_per_action_ratio"] = round(
            res.finished / (figure * actions / PUBLISHED_STEPS), 3)
    return out


def scale_runs(archive: Path, ticks: int, reassign: int, command: Sequence[str],
               names: Sequence[str] = (*INSTANCES, MILLION),
               station_cap: int | None = STATION_CAP) -> list[dict[str, Any]]:
    """Each instance of ``names`` whose files are there (the generated one always is), in its
    own process (its own peak RSS: ``command`` followed by ``--scale-one NAME --archive
    --ticks --reassign --station-cap`` prints :func:`scale_one` as one JSON line); an
    instance that is absent gives ``{"instance": name, "skipped": reason}``."""
    out: list[dict[str, Any]] = []
    for name in names:
        inst = INSTANCES.get(name)
        if inst is not None and not (archive / inst.path).is_file():
            out.append({"instance": name, "skipped": f"{inst.path} not under {archive}"})
            continue
        proc = subprocess.run(
            [*command, "--scale-one", name, "--archive", str(archive),
             "--ticks", str(ticks), "--reassign", str(reassign),
             "--station-cap", str(station_cap or 0)],
            capture_output=True, text=True, check=False)
        if proc.returncode:
            raise SystemExit(f"{name}: the run failed: "
                             f"{(proc.stderr.strip().splitlines() or ['?'])[-1]}")
        out.append(json.loads(proc.stdout.strip().splitlines()[-1]))
    return out


def scale_line(runs: list[dict[str, Any]]) -> str:
    """One result line of :func:`scale_runs`."""
    parts = []
    for r in runs:
        if "skipped" in r:
            parts.append(f"{r['instance']} skipped ({r['skipped']})")
            continue
        parts.append(
            f"{r['instance']} {r['robots']} robots x {r['ticks']} ticks: {r['finished']} tasks, "
            f"planner CPU per call p50 {r['cpu_p50_s']} s p99 {r['cpu_p99_s']} s max "
            f"{r['cpu_max_s']} s ({r['calls_over_1s']} of {r['calls']} calls over 1 s, the "
            f"first included, which took {r['first_call_s']} s after {r['preprocess_s']} s of "
            f"preprocessing; tables ahead between calls p99 "
            f"{r['warm_p99_s']} s), peak RSS {r['peak_rss_mb']} MB "
            f"(validator {r['validator_peak_rss_mb']} MB), valid"
            + (f"; vs WPPL {r['wppl_per_tick_ratio']} per tick / {r['wppl_per_action_ratio']} "
               f"per action, vs EPIBT {r['epibt_per_tick_ratio']} / "
               f"{r['epibt_per_action_ratio']}" if "wppl_per_tick_ratio" in r else ""))
    return "lifelong scale: " + "; ".join(parts)
