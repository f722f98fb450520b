"""Experiment campaigns (paper section 5): instances, the four variants, parallel runs, resume.

A campaign is a list of (map, agent count) groups, ``instances`` random instances per group
and ``seeds`` seeds per instance. Each instance is generated from a seed, planned ONCE (1-robust,
SOC-optimal) and kept in ``OUT/instances/`` as Solution JSON, so a rerun or a resumed run reuses
it. Each (instance, seed) is one experiment of four simulations in virtual time: ``lower_bound``
(no intruder), ``intruder``, ``random`` (intruder + one replan at a random time) and ``slack``
(intruder + slack-triggered replan), all from the same initial plan.

Rows are appended to ``OUT/results.csv`` as experiments complete (flushed, so an interruption
loses only the experiments in flight); a rerun skips the rows already there; at the end the file
is rewritten sorted. Work runs on a local process pool or, given a scheduler address, on a Dask
cluster, through the same ``concurrent.futures`` interface.
"""

from __future__ import annotations

import csv
import json
import os
import signal
import time
from collections.abc import Callable, Iterable, Iterator, Sequence
from concurrent.futures import (
    FIRST_COMPLETED,
    Executor,
    Future,
    ProcessPoolExecutor,
    as_completed,
    wait,
)
from contextlib import contextmanager
from dataclasses import asdict, dataclass, field
from functools import lru_cache
from pathlib import Path
from typing import Any, TypeVar

import numpy as np

from fleetgate.userio.files import atomic_open, make_folder, write_text
from gateway.execution.oneshot.policies import PolicyName
from gateway.execution.params import PAPER, IntruderReading
from gateway.planning.generators import random_instance
from gateway.planning.grid import Cell, Grid
from gateway.planning.motion import Motion
from gateway.planning.movingai import read_map
from gateway.planning.plan import NoSolution, Plan
from gateway.planning.seeds import derive_seed
from gateway.planning.solution_json import SolutionJson
from gateway.planning.solver import solve
from gateway.runtime.deadline import WallDeadline
from sim_clients.des import SimConfig, SimResult, parse_solver_time, run_simulation
from sim_clients.intruder import IntruderConfig
from sim_clients.stays import parse_stay

VARIANTS: tuple[str, ...] = ("lower_bound", "intruder", "random", "slack")
"""The four simulations of one experiment (the paper's)."""
EXTRA_VARIANTS: tuple[str, ...] = ("informed", "shadow", "reschedule", "reschedule+slack",
                                   "reschedule+informed")
"""Variants a campaign runs on request (``--informed``, ``--shadow``, ``--reschedule``): not
the paper's."""
ALL_VARIANTS = VARIANTS + EXTRA_VARIANTS
"""Every variant, in the order rows are sorted."""
HISTORY_VARIANTS: frozenset[str] = frozenset({"informed", "shadow", "reschedule",
                                              "reschedule+slack", "reschedule+informed"})
"""The variants whose runs use the block estimates (:mod:`gateway.execution.oneshot.blocks`), so
their rows depend on the block history they start from; the others never read it."""

COLUMNS: tuple[str, ...] = ("map", "agents", "instance", "seed", "variant", "soc_ms",
                            "makespan_ms", "replanned", "replan_at_ms", "solver_ms")
"""``results.csv`` columns (DESIGN section 3)."""

PAPER_GROUPS: tuple[tuple[str, int], ...] = (
    *(("lab", n) for n in (5, 10, 15)),
    *(("arena", n) for n in (10, 15, 20, 25)),
    *(("room-32-32-4", n) for n in (5, 10, 15)),
    *(("random-32-32-20", n) for n in (5, 10, 15)),
)
"""The paper's 13 (map, agents) groups; ``room-32-32-4`` stands in for its "room32-32-20",
which does not exist in the MovingAI benchmark (shared/maps/SOURCES.md)."""
PAPER_INSTANCES = 20
PAPER_SEEDS = 5

MAX_GENERATION_ATTEMPTS = 50
"""Instances generated per slot before giving up when the planner keeps failing."""

RowKey = tuple[str, int, int, int, str]
ExperimentKey = tuple[str, int, int, int]
T = TypeVar("T")
R = TypeVar("R")


class CampaignError(ValueError):
    """Bad campaign input or an output folder made with other settings."""


@dataclass(frozen=True)
class Row:
    """One line of ``results.csv``: one variant of one experiment."""

    map: str
    agents: int
    instance: int
    seed: int
    variant: str
    soc_ms: float
    makespan_ms: float
    replanned: bool
    replan_at_ms: float | None
    """When the policy first acted: decided a replan or (reschedule variants) switched Type 2
    edges; empty if it never did."""
    solver_ms: float

    @property
    def key(self) -> RowKey:
        """What identifies the row (the campaign never writes two rows with one key)."""
        return (self.map, self.agents, self.instance, self.seed, self.variant)

    def sort_key(self) -> tuple[str, int, int, int, int]:
        """The order of the final, sorted ``results.csv``."""
        return (self.map, self.agents, self.instance, self.seed,
                ALL_VARIANTS.index(self.variant))

    def to_csv(self) -> list[str]:
        """The row's CSV fields (times with at most 3 decimals, ``replanned`` as 0/1)."""
        at = "" if self.replan_at_ms is None else _fmt(self.replan_at_ms)
        return [self.map, str(self.agents), str(self.instance), str(self.seed), self.variant,
                _fmt(self.soc_ms), _fmt(self.makespan_ms), str(int(self.replanned)), at,
                _fmt(self.solver_ms)]

    @staticmethod
    def from_csv(fields: Sequence[str]) -> Row:
        """Parse the fields written by :meth:`to_csv` (ValueError on anything else)."""
        if len(fields) != len(COLUMNS):
            raise ValueError(f"expected {len(COLUMNS)} fields, got {len(fields)}")
        m, agents, inst, seed, variant, soc, mk, replanned, at, solver = fields
        if variant not in ALL_VARIANTS:
            raise ValueError(f"unknown variant {variant!r}")
        if replanned not in ("0", "1"):
            raise ValueError(f"replanned must be 0 or 1, got {replanned!r}")
        return Row(m, int(agents), int(inst), int(seed), variant, float(soc), float(mk),
                   replanned == "1", float(at) if at else None, float(solver))


def _fmt(value: float) -> str:
    text = f"{value:.3f}".rstrip("0").rstrip(".")
    return "0" if text == "-0" else text


@dataclass(frozen=True)
class SimSettings:
    """What every simulation of a campaign shares (the paper's defaults).

    ``solver_time`` is ``"measured"``, ``"zero"`` or a fixed number of ms as a string
    (DESIGN section 2: only zero or fixed makes runs exactly reproducible).
    ``replan_time_limit_s`` bounds each replanning solve; a replan that finds nothing in time
    keeps the old plan.
    """

    solver_time: str = "measured"
    threshold_ms: float = PAPER.threshold_ms
    intruder_appear_ms: float = PAPER.intruder_appear_ms
    intruder_leave_ms: float = PAPER.intruder_leave_ms
    replan_time_limit_s: float = 10.0
    intruder_reading: IntruderReading = "start"
    """:attr:`~sim_clients.intruder.IntruderConfig.reading`."""
    intruder_stay: str | None = None
    """The intruder's stay after its robot needs the cell (:mod:`sim_clients.stays`, its
    canonical text), drawn per experiment from the experiment's seed; None: the paper's fixed
    ``intruder_leave_ms``."""
    block_history_ms: tuple[float, ...] = ()
    """How long the blocks the fleets saw before each run lasted (a warm start of the block
    estimates of ``informed`` and ``shadow``; empty: every run starts cold)."""
    learned_blocks: int = 0
    """Learned block history (0: off): the runs of :data:`HISTORY_VARIANTS` start with the
    durations of the last ``learned_blocks`` blocks the fleet reported in the no-replan
    (``intruder``) runs of the experiments that come before theirs on the same map, in
    campaign order (:func:`learned_histories`); the first experiment of a map starts cold."""


@dataclass(frozen=True)
class CampaignSpec:
    """Which experiments a campaign runs; ``seed`` seeds instance generation."""

    groups: tuple[tuple[str, int], ...]
    instances: int
    seeds: int
    seed: int = 0
    plan_time_limit_s: float = 10.0
    sim: SimSettings = field(default_factory=SimSettings)
    motion: Motion = "omni"
    """The motion model of the plans; under ``turning`` every robot starts facing east
    (:data:`~gateway.planning.motion.DEFAULT_START_HEADING`: generated instances have none)."""
    extra_variants: tuple[str, ...] = ()
    """Variants run besides the paper's four (of :data:`EXTRA_VARIANTS`); a folder is reused
    with or without them (they only add rows)."""

    @property
    def variants(self) -> tuple[str, ...]:
        """The variants of every experiment, in row order."""
        return tuple(v for v in ALL_VARIANTS if v in VARIANTS or v in self.extra_variants)

    def __post_init__(self) -> None:
        if not self.groups:
            raise CampaignError("a campaign needs at least one map and agent count")
        for name, agents in self.groups:
            if agents < 1:
                raise CampaignError(f"{name}: the number of agents must be positive, "
                                    f"got {agents}")
        if self.instances < 1 or self.seeds < 1:
            raise CampaignError("--instances and --seeds must be positive")
        if self.plan_time_limit_s <= 0:
            raise CampaignError("--plan-time-limit must be positive")
        if self.sim.learned_blocks < 0:
            raise CampaignError("the learned block memory must be >= 0")
        if self.sim.learned_blocks and self.sim.block_history_ms:
            raise CampaignError("a block history is either learned or given, not both")

    def settings(self) -> dict[str, Any]:
        """The settings that change results; an output folder is only reused with equal ones."""
        return {"seed": self.seed, "plan_time_limit_s": self.plan_time_limit_s,
                "motion": self.motion, **asdict(self.sim),
                "block_history_ms": list(self.sim.block_history_ms)}  # as JSON reads it

    def slots(self) -> list[tuple[str, int, int]]:
        """Every instance slot ``(map, agents, index)`` in campaign order."""
        return [(m, n, i) for m, n in self.groups for i in range(self.instances)]

    def experiments(self) -> list[ExperimentKey]:
        """Every experiment ``(map, agents, index, seed)`` in campaign order (the order of
        ``--maps``/``--agents``, then instances, then seeds)."""
        return [(m, n, i, s) for m, n, i in self.slots()
                for s in self.experiment_seeds(m, n, i)]

    def experiment_seeds(self, map: str, agents: int, index: int) -> list[int]:
        """The simulation seeds of one instance (the ``seed`` column of ``results.csv``).

        Derived from the instance and the seed's number rather than 0..K-1: the simulator's
        random choices (the intruder's robot, the random replan time) would otherwise repeat
        across instances that share a seed number.
        """
        return [derive_seed(self.seed, map, agents, index, k, bits=31)
                for k in range(self.seeds)]


# ---------------------------------------------------------------------------------------------
# instances


@dataclass(frozen=True)
class InstanceRecord:
    """A generated instance with its initial plan (the file in ``OUT/instances/``)."""

    map: str
    agents: int
    index: int
    generator_seed: int
    attempts: int
    starts: tuple[Cell, ...]
    goals: tuple[Cell, ...]
    plan: Plan
    optimal: bool
    runtime_s: float
    expanded_nodes: int

    @property
    def filename(self) -> str:
        """``<map>-<agents>-<index>.json``."""
        return f"{self.map}-{self.agents}-{self.index:03d}.json"

    def to_json(self, campaign_seed: int) -> dict[str, Any]:
        """Solution JSON (DESIGN section 3) plus an ``instance`` block saying how it was made."""
        solution = SolutionJson(self.map, self.starts, self.goals, self.plan, self.optimal,
                                self.runtime_s, self.expanded_nodes)
        return {
            **solution.to_json(),
            "instance": {"campaign_seed": campaign_seed, "agents": self.agents,
                         "index": self.index, "generator_seed": self.generator_seed,
                         "attempts": self.attempts},
        }

    @staticmethod
    def from_json(data: dict[str, Any]) -> InstanceRecord:
        """Inverse of :meth:`to_json` (KeyError/ValueError/TypeError on a malformed file)."""
        meta = data["instance"]
        solution = SolutionJson.from_json(data)
        if len(solution.starts) != meta["agents"]:
            raise ValueError(f"{len(solution.starts)} agents listed, the header says "
                             f"{meta['agents']}")
        return InstanceRecord(
            map=solution.map, agents=int(meta["agents"]), index=int(meta["index"]),
            generator_seed=int(meta["generator_seed"]), attempts=int(meta["attempts"]),
            starts=tuple((s[0], s[1]) for s in solution.starts), goals=solution.goals,
            plan=solution.plan,
            optimal=solution.optimal, runtime_s=solution.runtime_s,
            expanded_nodes=solution.expanded_nodes)


@dataclass(frozen=True)
class PlanTask:
    """Generate and plan one instance slot (runs in a worker)."""

    map: str
    map_path: str
    agents: int
    index: int
    campaign_seed: int
    time_limit_s: float
    motion: Motion = "omni"


@lru_cache(maxsize=16)
def load_grid(map_path: str) -> Grid:
    """The grid of a map file, read once per worker process."""
    return read_map(map_path)


def plan_instance(task: PlanTask) -> InstanceRecord:
    """Generate instances from derived seeds until the planner solves one within the limit."""
    grid = load_grid(task.map_path)
    for attempt in range(MAX_GENERATION_ATTEMPTS):
        gen_seed = derive_seed(task.campaign_seed, task.map, task.agents, task.index, attempt)
        inst = random_instance(grid, task.agents, np.random.default_rng(gen_seed))
        starts = inst.starts if task.motion == "omni" else inst.turning_starts()
        began = time.perf_counter()
        try:
            solution = solve(grid, starts, inst.goals, motion=task.motion,
                             deadline=WallDeadline(task.time_limit_s))
        except NoSolution:
            continue
        return InstanceRecord(task.map, task.agents, task.index, gen_seed, attempt + 1,
                              inst.starts, inst.goals, solution.plan, solution.optimal,
                              round(time.perf_counter() - began, 6), solution.expanded_nodes)
    raise CampaignError(f"{task.map} with {task.agents} agents: no instance out of "
                        f"{MAX_GENERATION_ATTEMPTS} was solved within {task.time_limit_s} s")


# ---------------------------------------------------------------------------------------------
# experiments


@dataclass(frozen=True)
class ExperimentTask:
    """Run the missing variants of one (instance, seed) (runs in a worker)."""

    map_path: str
    record: InstanceRecord
    seed: int
    variants: tuple[str, ...]
    sim: SimSettings
    history: tuple[float, ...] | None = None
    """The block history the :data:`HISTORY_VARIANTS` start from instead of the settings'
    (the learned one)."""


VARIANT_CONFIG: dict[str, tuple[bool, PolicyName, bool]] = {
    "lower_bound": (False, "none", False), "intruder": (True, "none", False),
    "random": (True, "random", False), "slack": (True, "slack", False),
    "informed": (True, "informed", False), "shadow": (True, "shadow", False),
    "reschedule": (True, "reschedule", False),
    "reschedule+slack": (True, "reschedule+slack", False),
    "reschedule+informed": (True, "reschedule+slack", True)}
"""Each variant as (intruder on, replanning policy, informed replanning besides the policy's
own). ``informed`` replans when the slack policy does, with the blocks the fleet reported as
obstacles; ``shadow`` solves in the background and adopts a plan when the estimate says it
pays; ``reschedule`` only switches Type 2 edges, ``reschedule+slack`` does that first and
replans when the slack policy does, ``reschedule+informed`` too, informed."""


def variant_config(grid: Grid, plan: Plan, seed: int, variant: str,
                   sim: SimSettings, history: tuple[float, ...] | None = None) -> SimConfig:
    """The simulation of ``variant`` from the instance's initial plan (a variant of
    :data:`HISTORY_VARIANTS` starts from ``history`` if given)."""
    intruder, policy, informed = VARIANT_CONFIG[variant]
    if history is None or variant not in HISTORY_VARIANTS:
        history = sim.block_history_ms
    return SimConfig(
        grid=grid, plan=plan, seed=seed, intruder=intruder, policy=policy, informed=informed,
        threshold_ms=sim.threshold_ms, solver_time=parse_solver_time(sim.solver_time),
        solver_time_limit_s=sim.replan_time_limit_s, block_history=history,
        intruder_config=IntruderConfig(appear_ms=sim.intruder_appear_ms,
                                       leave_ms=sim.intruder_leave_ms,
                                       reading=sim.intruder_reading),
        intruder_stay=None if sim.intruder_stay is None else parse_stay(sim.intruder_stay))


def simulate_variant(grid: Grid, plan: Plan, seed: int, variant: str,
                     sim: SimSettings, history: tuple[float, ...] | None = None) -> SimResult:
    """One simulation of ``variant`` from the instance's initial plan."""
    return run_simulation(variant_config(grid, plan, seed, variant, sim, history))


@dataclass(frozen=True)
class Failure:
    """A simulation that raised instead of finishing (reported; its row is missing)."""

    map: str
    agents: int
    instance: int
    seed: int
    variant: str
    error: str


@dataclass(frozen=True)
class Blocks:
    """One line of ``blocks.csv``: how long each block the fleet reported in one experiment's
    no-replan (``intruder``) run lasted, in the order they cleared."""

    key: ExperimentKey
    durations_ms: tuple[float, ...]


Outcome = tuple[list[Row], list[Failure], Blocks | None]


def run_experiment(task: ExperimentTask) -> Outcome:
    """Simulate each requested variant of one experiment from the instance's initial plan;
    with the ``intruder`` variant, also what its blocks lasted.

    A variant whose simulation raises is reported as a :class:`Failure` instead of stopping
    the campaign (its experiment stays incomplete and a rerun tries it again).
    """
    grid = load_grid(task.map_path)
    rec = task.record
    rows, failures, blocks = [], [], None
    for variant in task.variants:
        try:
            res = simulate_variant(grid, rec.plan, task.seed, variant, task.sim, task.history)
        except Exception as exc:  # one bad run must not sink a long campaign
            failures.append(Failure(rec.map, rec.agents, rec.index, task.seed, variant,
                                    f"{type(exc).__name__}: {exc}"))
            continue
        acted = [t for t in (res.replan_at_ms, res.reschedule_at_ms) if t is not None]
        rows.append(Row(rec.map, rec.agents, rec.index, task.seed, variant, res.soc_ms,
                        res.makespan_ms, res.replans > 0, min(acted, default=None),
                        res.solver_ms))
        if variant == "intruder":
            blocks = Blocks((rec.map, rec.agents, rec.index, task.seed), res.blocks_ms)
    return rows, failures, blocks


def learned_histories(order: Sequence[ExperimentKey], blocks: dict[ExperimentKey, Blocks],
                      memory: int) -> dict[ExperimentKey, tuple[float, ...]]:
    """The learned block history of each experiment of ``order`` (campaign order): the last
    ``memory`` durations of the blocks reported in the experiments before it on the same map
    (never its own, never a later one's), oldest first. An experiment is left out if an
    earlier one on its map has no recorded blocks yet (its history is not known)."""
    out: dict[ExperimentKey, tuple[float, ...]] = {}
    seen: dict[str, list[float]] = {}
    broken: set[str] = set()
    for key in order:
        m = key[0]
        if m in broken:
            continue
        past = seen.setdefault(m, [])
        out[key] = tuple(past[-memory:]) if memory else ()
        got = blocks.get(key)
        if got is None:
            broken.add(m)
        else:
            past.extend(got.durations_ms)
    return out


def run_chunk(tasks: Sequence[ExperimentTask]) -> list[Outcome]:
    """Run several experiments in one worker call (fewer round trips than one per task)."""
    return [run_experiment(t) for t in tasks]


# ---------------------------------------------------------------------------------------------
# results.csv


def read_results(path: Path) -> list[Row]:
    """Rows of a ``results.csv`` (none if it does not exist).

    A last line cut short by an interruption is dropped (and cut from the file) so that a
    resumed run writes clean rows after it; any other malformed line is an error.
    """
    if not path.exists():
        return []
    text = path.read_text()
    lines = text.splitlines(keepends=True)
    if lines and not lines[-1].endswith("\n"):
        with path.open("r+") as f:
            f.truncate(len(text.encode()) - len(lines[-1].encode()))
        lines = lines[:-1]
    reader = csv.reader(lines)
    header = next(reader, None)
    if header is None:
        return []
    if tuple(header) != COLUMNS:
        raise CampaignError(f"{path}: unexpected header {','.join(header)}")
    rows = []
    for number, fields in enumerate(reader, start=2):
        try:
            rows.append(Row.from_csv(fields))
        except ValueError as exc:
            raise CampaignError(f"{path}:{number}: {exc}") from None
    return rows


def write_results(path: Path, rows: Iterable[Row]) -> None:
    """Write all rows sorted, atomically (a temporary file renamed over ``path``)."""
    with atomic_open(path, newline="") as f:
        writer = csv.writer(f, lineterminator="\n")
        writer.writerow(COLUMNS)
        writer.writerows(r.to_csv() for r in sorted(rows, key=Row.sort_key))


def appended_csv_rows(path: Path, columns: Sequence[str]) -> Iterator[tuple[int, list[str]]]:
    """The numbered rows (from line 2) of a CSV file written by appending (``blocks.csv``,
    ``oracle.csv``): none if it does not exist, a last line cut short by an interruption
    dropped; a :class:`CampaignError` if its header is not ``columns``."""
    if not path.exists():
        return
    lines = path.read_text().splitlines(keepends=True)
    if lines and not lines[-1].endswith("\n"):
        lines = lines[:-1]
    reader = csv.reader(lines)
    if tuple(next(reader, columns)) != tuple(columns):
        raise CampaignError(f"{path}: unexpected header (expected {','.join(columns)})")
    yield from enumerate(reader, start=2)

BLOCKS_COLUMNS: tuple[str, ...] = ("map", "agents", "instance", "seed", "blocks_ms")
"""``blocks.csv`` columns: an experiment and its intruder run's block durations, ``;``-joined
(empty if the fleet reported no block)."""


def read_blocks(path: Path) -> dict[ExperimentKey, Blocks]:
    """The experiments' blocks in ``blocks.csv`` (none if it does not exist; a last line cut
    short by an interruption is dropped)."""
    out = {}
    for number, fields in appended_csv_rows(path, BLOCKS_COLUMNS):
        try:
            m, agents, inst, seed, durations = fields
            key = (m, int(agents), int(inst), int(seed))
            out[key] = Blocks(key, tuple(float(d) for d in durations.split(";") if d))
        except ValueError as exc:
            raise CampaignError(f"{path}:{number}: {exc}") from None
    return out


class _Appender:
    """Appends lines to a CSV file (``results.csv``, ``blocks.csv``) and flushes after each
    batch."""

    def __init__(self, path: Path, header: Sequence[str]) -> None:
        if path.exists() and not path.read_bytes().endswith(b"\n"):
            with path.open("r+b") as f:  # a line cut short by an interruption
                f.truncate(f.read().rfind(b"\n") + 1)
        fresh = not path.exists() or path.stat().st_size == 0
        self._file = path.open("a", newline="")
        self._writer = csv.writer(self._file, lineterminator="\n")
        if fresh:
            self._writer.writerow(header)
            self._file.flush()

    def append(self, lines: Iterable[Sequence[str]]) -> None:
        self._writer.writerows(lines)
        self._file.flush()

    def close(self) -> None:
        self._file.close()


# ---------------------------------------------------------------------------------------------
# running


Progress = Callable[[str, int, int], None]
"""``progress(phase, done, total)``; phase is ``"instances"`` or ``"experiments"``."""


@dataclass
class CampaignResult:
    """What a run did: the rows of the spec (old and new) and the counts of new work."""

    rows: list[Row]
    planned: int
    ran: int
    complete: bool
    failures: list[Failure]
    planning_s: float = 0.0
    """Wall time of the instance phase (generating and planning)."""
    running_s: float = 0.0
    """Wall time of the experiment phase (simulations, replans included)."""
    records: dict[tuple[str, int, int], InstanceRecord] = field(default_factory=dict)
    """The instances by slot ``(map, agents, index)``."""
    blocks: dict[ExperimentKey, Blocks] = field(default_factory=dict)
    """What the blocks of each experiment's intruder run lasted (``blocks.csv``)."""


SCHEDULER_CONNECT_S = 5.0
"""How long to try reaching a Dask scheduler before giving up (Dask's default is 30 s)."""


def _quiet_ctrl_c() -> None:
    """A pool worker ends quietly on Ctrl-C (a terminal's SIGINT reaches the whole process
    group: an idle worker printed its KeyboardInterrupt traceback); the campaign itself
    drops the queued work and exits 130."""
    signal.signal(signal.SIGINT, _exit_quietly)


def _exit_quietly(signum: int, frame: object) -> None:
    # os._exit, not SystemExit: a handler's exception raised while numba's compiler is in a
    # ctypes callback is "ignored" with its traceback printed; the worker holds nothing the
    # user asked for (the campaign writes the results)
    os._exit(130)


@contextmanager
def open_executor(workers: int = 1,
                  scheduler: str | None = None) -> Iterator[tuple[Executor, int]]:
    """A process pool of ``workers`` processes, or an executor on a Dask cluster's scheduler.

    Yields the executor and how many tasks it runs at once (a Dask cluster's total threads).
    """
    if scheduler is None:
        pool = ProcessPoolExecutor(max_workers=workers, initializer=_quiet_ctrl_c)
        try:
            yield pool, workers
        except BaseException:
            pool.shutdown(wait=False, cancel_futures=True)  # Ctrl-C: drop the queued work
            raise
        pool.shutdown()
        return
    try:
        from distributed import Client
    except ImportError as exc:
        raise CampaignError("--scheduler needs dask.distributed (pip install "
                            "'fleetgate[dask]')") from exc
    try:
        client = Client(scheduler, timeout=SCHEDULER_CONNECT_S)
    except (OSError, TimeoutError) as exc:
        raise CampaignError(f"cannot reach the Dask scheduler at {scheduler} within "
                            f"{SCHEDULER_CONNECT_S:g} s ({type(exc).__name__})") from None
    with client:
        threads = sum(w.get("nthreads", 1) for w in client.scheduler_info()["workers"].values())
        yield client.get_executor(pure=False), max(1, threads)


HISTORY_SETTINGS = frozenset({"block_history_ms", "learned_blocks"})
"""The settings only the rows of :data:`HISTORY_VARIANTS` depend on."""


def _check_settings(out: Path, spec: CampaignSpec) -> None:
    path = out / "campaign.json"
    settings = spec.settings()
    if path.exists():
        # A setting added since the folder was made had its default value there.
        default = CampaignSpec(spec.groups, 1, 1).settings()
        old = {**default, **json.loads(path.read_text())}
        diff = sorted(k for k in settings if old.get(k) != settings[k])
        if set(diff) <= HISTORY_SETTINGS and not any(
                r.variant in HISTORY_VARIANTS for r in read_results(out / "results.csv")):
            diff = []  # no row there depends on them
        if diff:
            hint = " (--block-history none: a cold one)" if set(diff) & HISTORY_SETTINGS else ""
            raise CampaignError(
                f"{out} holds a campaign made with other settings ("
                + ", ".join(f"{k}: {old.get(k)!r} there, {settings[k]!r} now" for k in diff)
                + f"); use another --out or the same settings{hint}")
    write_text(path, json.dumps(settings, indent=2) + "\n")


def _load_instances(folder: Path, spec: CampaignSpec,
                    slots: Sequence[tuple[str, int, int]]) -> dict[tuple[str, int, int],
                                                                   InstanceRecord]:
    found = {}
    for m, n, i in slots:
        path = folder / f"{m}-{n}-{i:03d}.json"
        if not path.exists():
            continue
        try:
            data = json.loads(path.read_text())
            rec = InstanceRecord.from_json(data)
        except (ValueError, KeyError, TypeError) as exc:
            raise CampaignError(f"{path}: not an instance file of a campaign ({exc})") from None
        if (rec.map, rec.agents, rec.index) != (m, n, i) or \
                data["instance"]["campaign_seed"] != spec.seed:
            raise CampaignError(f"{path} belongs to another campaign; use another --out")
        found[(m, n, i)] = rec
    return found


def chunked(items: Sequence[T], size: int) -> list[Sequence[T]]:
    """``items`` in consecutive pieces of ``size``."""
    return [items[k:k + size] for k in range(0, len(items), size)]


def run_campaign(spec: CampaignSpec, out: Path, map_paths: dict[str, str], *,
                 executor: Executor, workers: int = 1, limit: int | None = None,
                 progress: Progress | None = None, chunk_size: int | None = None,
                 in_flight_chunks: int = 2) -> CampaignResult:
    """Plan the missing instances, run the missing experiments, leave a sorted results.csv.

    ``map_paths`` maps each map name of the spec to its file; ``workers`` is how many
    processes ``executor`` runs tasks on (for chunking). ``limit`` stops after that many
    new experiments (an interrupted campaign, for testing resume). At most
    ``in_flight_chunks`` chunks per worker are queued at a time, so an interruption loses at
    most those.
    """
    missing_maps = sorted({m for m, _ in spec.groups} - set(map_paths))
    if missing_maps:
        raise CampaignError(f"no map file given for {', '.join(missing_maps)}")
    make_folder(out)
    _check_settings(out, spec)
    folder = make_folder(out / "instances")
    report = progress or (lambda _phase, _done, _total: None)

    slots = spec.slots()
    records = _load_instances(folder, spec, slots)
    todo = [PlanTask(m, map_paths[m], n, i, spec.seed, spec.plan_time_limit_s, spec.motion)
            for m, n, i in slots if (m, n, i) not in records]
    report("instances", len(records), len(slots))
    began = time.perf_counter()
    for planned in as_completed([executor.submit(plan_instance, t) for t in todo]):
        rec = planned.result()
        path = folder / rec.filename
        write_text(path, json.dumps(rec.to_json(spec.seed)) + "\n")
        records[(rec.map, rec.agents, rec.index)] = rec
        report("instances", len(records), len(slots))

    planning_s = time.perf_counter() - began
    results_path = out / "results.csv"
    existing = read_results(results_path)
    done = {r.key for r in existing}
    blocks_path = out / "blocks.csv"
    blocks = read_blocks(blocks_path)
    order = spec.experiments()
    left = {k: [v for v in spec.variants if (*k, v) not in done] for k in order}
    learned = spec.sim.learned_blocks > 0

    def task(key: ExperimentKey, variants: Sequence[str],
             history: tuple[float, ...] | None = None) -> ExperimentTask:
        m, n, i, seed = key
        return ExperimentTask(map_paths[m], records[(m, n, i)], seed, tuple(variants),
                              spec.sim, history)

    # Learned history: first every run that does not depend on it (and the intruder run of
    # every experiment whose blocks are not recorded), then, knowing every experiment's
    # blocks, the history variants.
    first = []
    for k, variants in left.items():
        now = [v for v in variants if not (learned and v in HISTORY_VARIANTS)]
        if learned and k not in blocks and "intruder" not in now:
            now.insert(0, "intruder")
        if now:
            first.append(task(k, now))
    budget = None if limit is None else max(0, limit)
    if budget is not None:
        first = first[:budget]
        budget -= len(first)
    total = len(order)
    finished = sum(1 for v in left.values() if not v)
    new_rows: list[Row] = []
    failures: list[Failure] = []
    report("experiments", finished, total)
    began = time.perf_counter()
    appender = _Appender(results_path, COLUMNS)
    block_log = _Appender(blocks_path, BLOCKS_COLUMNS)
    failure_log = (out / "failures.jsonl").open("w")  # this run's failures (retried on rerun)
    ran: set[ExperimentKey] = set()

    def run_tasks(tasks: list[ExperimentTask]) -> None:
        nonlocal finished
        ran.update((t.record.map, t.record.agents, t.record.index, t.seed) for t in tasks)
        # The largest fleets first: the long tasks do not straggle at the end.
        tasks.sort(key=lambda t: -t.record.agents)
        size = chunk_size or max(1, min(8, len(tasks) // (workers * 16)))
        for outcomes in run_chunks(executor, run_chunk, chunked(tasks, size),
                                   in_flight_chunks * workers):
            for rows, failed, got in outcomes:
                if got is not None and got.key not in blocks:
                    blocks[got.key] = got
                    block_log.append([[*map(str, got.key),
                                       ";".join(_fmt(d) for d in got.durations_ms)]])
                rows = [r for r in rows if r.key not in done]  # (an intruder rerun)
                done.update(r.key for r in rows)
                appender.append(r.to_csv() for r in rows)
                new_rows.extend(rows)
                failures.extend(failed)
                failure_log.writelines(json.dumps(asdict(x)) + "\n" for x in failed)
                failure_log.flush()
                for r in rows:
                    waiting = left[r.key[:4]]
                    waiting.remove(r.variant)
                    finished += not waiting
            report("experiments", finished, total)

    try:
        run_tasks(first)
        if learned:
            histories = learned_histories(order, blocks, spec.sim.learned_blocks)
            second = [task(k, v, histories[k]) for k, v in left.items()
                      if v and k in histories]
            run_tasks(second if budget is None else second[:budget])
    finally:
        appender.close()
        block_log.close()
        failure_log.close()

    running_s = time.perf_counter() - began
    rows = existing + new_rows
    write_results(results_path, rows)
    wanted = {(*k, v) for k in order for v in spec.variants}
    mine = [r for r in rows if r.key in wanted]
    return CampaignResult(sorted(mine, key=Row.sort_key), len(todo), len(ran),
                          len(mine) == len(wanted), failures, round(planning_s, 3),
                          round(running_s, 3), records, blocks)


def run_chunks(executor: Executor, fn: Callable[[Sequence[T]], R],
               chunks: Iterable[Sequence[T]], in_flight: int) -> Iterator[R]:
    """``fn(chunk)`` of every chunk on ``executor``, at most ``in_flight`` queued at a time;
    yields the results as they complete."""
    pending: set[Future[R]] = set()
    queue = iter(chunks)
    while True:
        while len(pending) < max(1, in_flight):
            chunk = next(queue, None)
            if chunk is None:
                break
            pending.add(executor.submit(fn, chunk))
        if not pending:
            return
        ready, pending = wait(pending, return_when=FIRST_COMPLETED)
        for fut in ready:
            yield fut.result()
