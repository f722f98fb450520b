"""The replanning oracle: one forced replan at every step of a run, the best one kept.

For one experiment (instance + seed) the oracle runs the intruder variant without replanning
and, at every ``step_ms`` of virtual time (0, step, 2 step, ... until the run ends), forks the
run and forces a single replan there (an operator's "replan now"); each fork runs to the end.
The oracle's SOC is the smallest of all these and of not replanning at all: what the best
moment to replan once would have given. No online policy can know it (it sees the future);
it is the yardstick of :mod:`experiments.oracle_stats`.

Two memos make the sweep cheap, both exact:

* solves: the same start configuration gives the same plan (and, under ``--solver-time
  measured``, the same charge: the first solve's);
* continuations: when a fork adopts its new plan, the rest of its run is a function of the
  time, the robots' cells, headings and completion times, the intruder's state and the events
  still due; forks that reach an equal state (a replan decided anywhere between the same two
  robot starts, typically) share one simulation of the rest.

A test checks that the memoised, forking sweep gives exactly what one fresh simulation per
replan time gives.

The clairvoyant (``clairvoyant=True``, ``fleetgate experiment --clairvoyant``) sweeps the same
way, but knows the intruder's cell and leave time from the moment it appears: its forced
replans start at ``T_a`` and are informed solves that keep every robot off the intruder's cell
until it truly leaves; the sweep ends when the intruder is gone (a later replan is the
oracle's, uninformed). It is the yardstick of what replanning could save with perfect
knowledge of the block (:mod:`experiments.clairvoyant_stats`).
"""

from __future__ import annotations

import csv
import dataclasses
import time
from collections.abc import Iterable, Sequence
from concurrent.futures import Executor
from dataclasses import astuple, dataclass, field, fields
from pathlib import Path
from typing import Any

import numpy as np

from experiments.campaign import (
    CampaignError,
    CampaignSpec,
    Failure,
    InstanceRecord,
    Progress,
    SimSettings,
    appended_csv_rows,
    chunked,
    load_grid,
    run_chunks,
    variant_config,
)
from gateway.execution.commands import SolveRequest
from gateway.execution.params import PAPER
from gateway.planning.plan import Plan
from gateway.planning.seeds import derive_seed
from sim_clients.des import SimConfig, Simulation
from sim_clients.intruder import IntruderState

DEFAULT_STEP_MS = PAPER.oracle_step_ms
"""The sweep's step in virtual ms (the executor ticks every 100 ms)."""

CAVEATS: tuple[str, ...] = (
    "The oracle knows the future: it tries one forced replan at every step and keeps the best; "
    "no online policy can match it in general.",
    "A forced replan before the intruder appears (T_a) changes the plan the intruder picks its "
    "robot and cell from, so early oracle replans can win by changing whom the intruder "
    "blocks (best_after_appear gives the oracle restricted to replans at or after T_a).",
    "The sweep's grid (the step) and the executor's 100 ms ticks and the robots' 100 ms "
    "re-checks make times coarse: a policy can beat the oracle by replanning between two "
    "steps, so a capture above 100% is possible.",
    "Under --solver-time measured, the solver's CPU time is charged; a memoised solve is "
    "charged what its first solve cost.",
)
"""What the oracle's numbers do not say, printed with them."""


Outcome = tuple[float, float]
"""``(soc_ms, makespan_ms)`` of a finished run."""


@dataclass
class Memo:
    """The sweep's memos (shared by every fork of one experiment)."""

    solves: dict[tuple[Any, ...], tuple[Plan | None, float]] = field(default_factory=dict)
    outcomes: dict[tuple[Any, ...], Outcome] = field(default_factory=dict)


class _OracleSimulation(Simulation):
    """A simulation whose solves and post-replan continuations are memoised."""

    def __init__(self, config: SimConfig, memo: Memo) -> None:
        super().__init__(config)
        self.memo = memo
        self.known: Outcome | None = None
        """The outcome of this fork, found in the memo instead of simulated."""
        self.state_key: tuple[Any, ...] | None = None
        """The fingerprint this fork's continuation is memoised under."""

    def plan_for(self, request: SolveRequest, now: float) -> tuple[Plan | None, float]:
        if request.obstacles:  # (not from the oracle's own replans) no memo
            return super().plan_for(request, now)
        key = (request.starts, request.headings)
        got = self.memo.solves.get(key)
        if got is None:
            got = self.memo.solves[key] = super().plan_for(request, now)
        return got

    def solved(self, now: float) -> None:
        if self.pending_plan is not None:  # an abandoned replan resumes the old plan: no key
            key = self._fingerprint(now)
            self.known = self.memo.outcomes.get(key)
            if self.known is not None:
                return
            self.state_key = key
        super().solved(now)

    def _fingerprint(self, now: float) -> tuple[Any, ...]:
        """Everything the rest of the run depends on once every robot is idle and the new
        plan (a function of the robots' cells) is about to be adopted."""
        ex = self.executor
        n = len(self.robots)
        intr = self.intruder
        return (now, tuple(ex.robot_cell(k) for k in range(n)),
                tuple(ex.robot_heading(k) for k in range(n)), ex.completions_ms,
                None if intr is None else (intr.state, intr.cell, intr.next_wakeup_ms()),
                tuple(sorted((t, kind, who) for t, kind, _, who in self.heap)))

    def finished(self) -> bool:
        return self.known is not None or super().finished()

    def outcome(self) -> Outcome:
        """The finished fork's SOC and makespan (memoising it)."""
        if self.known is not None:
            return self.known
        assert self.completed is not None
        got = (self.completed.soc_ms, self.completed.makespan_ms)
        if self.state_key is not None:
            self.memo.outcomes[self.state_key] = got
        return got


class ClairvoyantSimulation(_OracleSimulation):
    """An oracle simulation whose replans know the intruder's cell and leave time."""

    def plan_for(self, request: SolveRequest, now: float) -> tuple[Plan | None, float]:
        intr = self.intruder
        if (intr is None or intr.cell is None or request.shadow
                or intr.state not in (IntruderState.WAITING, IntruderState.PRESENT)
                or intr.cell in request.starts):
            return super().plan_for(request, now)
        request = dataclasses.replace(request, obstacles=((intr.cell, self.held_until(now)),),
                                      start_ms=None)
        # the plan is a function of the starts, headings and forbidden timesteps
        key = (request.starts, request.headings,
               tuple(request.forbidden(now, self.cfg.action_ms)))
        got = self.memo.solves.get(key)
        if got is None:
            got = self.memo.solves[key] = Simulation.plan_for(self, request, now)
        return got

    def held_until(self, now: float) -> float:
        """Until when a replan at ``now`` keeps the intruder's cell free: when it leaves."""
        assert self.intruder is not None
        return self.intruder.leave_ms


@dataclass(frozen=True)
class Sweep:
    """One experiment's oracle sweep (times in virtual ms)."""

    none_soc_ms: float
    """SOC without any replan (the campaign's ``intruder`` variant)."""
    curve: tuple[tuple[float, float], ...]
    """``(replan time, SOC)`` of every forced replan, in time order."""
    solves: int
    """Distinct solves (the rest came from the memo)."""
    continuations: int
    """Forks simulated after their replan (the rest came from the memo)."""

    def best(self, not_before_ms: float = 0.0) -> tuple[float, float | None]:
        """The smallest SOC of no replan and of the replans at or after ``not_before_ms``, with
        its replan time (None: not replanning is best; ties go to not replanning, then to the
        earliest replan)."""
        soc, at = self.none_soc_ms, None
        for t, s in self.curve:
            if t >= not_before_ms and s < soc:
                soc, at = s, t
        return soc, at


def sweep(config: SimConfig, step_ms: float = DEFAULT_STEP_MS, *,
          clairvoyant: bool = False) -> Sweep:
    """Sweep one forced replan every ``step_ms`` over the run of ``config`` (which must have no
    replanning policy of its own and a replan budget); ``clairvoyant``: from ``T_a`` while the
    intruder is there, each replan knowing its cell and leave time."""
    if not step_ms > 0:
        raise ValueError(f"the sweep's step must be positive, got {step_ms}")
    if config.policy != "none" or config.max_replans < 1:
        raise ValueError("the oracle forces its own replans: give policy 'none' and "
                         "max_replans >= 1")
    memo = Memo()
    return sweep_from((ClairvoyantSimulation if clairvoyant else _OracleSimulation)(config, memo),
                      step_ms, clairvoyant=clairvoyant)


def sweep_from(base: _OracleSimulation, step_ms: float, *, clairvoyant: bool = False) -> Sweep:
    """:func:`sweep` from its base simulation ``base`` (not started; a subclass may watch the
    run, e.g. :mod:`experiments.stay_info`)."""
    config, memo = base.cfg, base.memo
    base.start()
    curve = []
    t = config.intruder_config.appear_ms if clairvoyant else 0.0
    while True:
        base.run_until(t)
        if base.finished() or (clairvoyant and (
                base.intruder is None or base.intruder.state is IntruderState.GONE)):
            break
        fork = base.fork(share=(memo,))
        fork.replan_now(t)
        fork.run_until(None)
        curve.append((t, fork.outcome()[0]))
        t += step_ms
    base.run_until(None)
    assert base.completed is not None
    return Sweep(base.completed.soc_ms, tuple(curve), len(memo.solves), len(memo.outcomes))


# ---------------------------------------------------------------------------------------------
# oracle.csv


@dataclass(frozen=True)
class OracleRow:
    """One line of ``oracle.csv``: the oracle of one experiment."""

    map: str
    agents: int
    instance: int
    seed: int
    step_ms: float
    none_soc_ms: float
    best_soc_ms: float
    best_at_ms: float | None
    best_after_appear_soc_ms: float
    best_after_appear_at_ms: float | None
    replans: int
    solves: int
    continuations: int
    cpu_s: float
    """CPU time of the sweep in its worker (the measured cost)."""

    @property
    def key(self) -> tuple[str, int, int, int]:
        """The experiment (as in ``results.csv``)."""
        return (self.map, self.agents, self.instance, self.seed)

    @staticmethod
    def of(key: tuple[str, int, int, int], step_ms: float, s: Sweep, appear_ms: float,
           cpu_s: float) -> OracleRow:
        """The row of one finished sweep."""
        best, at = s.best()
        after, after_at = s.best(appear_ms)
        return OracleRow(*key, step_ms, s.none_soc_ms, best, at, after, after_at, len(s.curve),
                         s.solves, s.continuations, round(cpu_s, 4))


ORACLE_COLUMNS = tuple(f.name for f in fields(OracleRow))


def _cell(value: object) -> str:
    return "" if value is None else str(value)


def write_oracle_rows(path: Path, rows: Iterable[OracleRow], *, append: bool) -> None:
    """Write (or append, with a header on a new file) rows to ``oracle.csv``."""
    fresh = not append or not path.exists() or path.stat().st_size == 0
    with path.open("a" if append else "w", newline="") as f:
        writer = csv.writer(f, lineterminator="\n")
        if fresh:
            writer.writerow(ORACLE_COLUMNS)
        writer.writerows([_cell(v) for v in astuple(r)] for r in rows)


def read_oracle_rows(path: Path) -> list[OracleRow]:
    """The rows of ``oracle.csv`` (none if missing; a last line cut short is dropped)."""
    out = []
    for number, cells in appended_csv_rows(path, ORACLE_COLUMNS):
        try:
            out.append(_parse_row(cells))
        except (TypeError, ValueError) as exc:
            raise ValueError(f"{path}:{number}: {exc}") from None
    return out


def _parse_row(cells: Sequence[str]) -> OracleRow:
    if len(cells) != len(ORACLE_COLUMNS):
        raise ValueError(f"expected {len(ORACLE_COLUMNS)} fields, got {len(cells)}")
    values: list[Any] = []
    for f, text in zip(fields(OracleRow), cells, strict=True):
        kind = str(f.type)
        if kind == "str":
            values.append(text)
        elif kind == "int":
            values.append(int(text))
        elif kind.endswith("| None"):
            values.append(float(text) if text else None)
        else:
            values.append(float(text))
    return OracleRow(*values)


# ---------------------------------------------------------------------------------------------
# running the oracle of a campaign


@dataclass(frozen=True)
class OracleTask:
    """Sweep the oracle of one experiment (runs in a worker)."""

    map_path: str
    record: InstanceRecord
    seed: int
    sim: SimSettings
    step_ms: float
    clairvoyant: bool = False


def run_oracle_task(task: OracleTask) -> OracleRow | Failure:
    """The oracle row of one experiment, or a :class:`Failure` if its simulation raised."""
    rec = task.record
    config = variant_config(load_grid(task.map_path), rec.plan, task.seed, "intruder", task.sim)
    began = time.process_time()
    try:
        got = sweep(config, task.step_ms, clairvoyant=task.clairvoyant)
    except Exception as exc:  # one bad run must not sink a long sweep
        return Failure(rec.map, rec.agents, rec.index, task.seed,
                       "clairvoyant" if task.clairvoyant else "oracle",
                       f"{type(exc).__name__}: {exc}")
    return OracleRow.of((rec.map, rec.agents, rec.index, task.seed), task.step_ms, got,
                        task.sim.intruder_appear_ms, time.process_time() - began)


def run_oracle_chunk(tasks: Sequence[OracleTask]) -> list[OracleRow | Failure]:
    """Several sweeps in one worker call."""
    return [run_oracle_task(t) for t in tasks]


ExperimentKey = tuple[str, int, int, int]


def sample_experiments(keys: Sequence[ExperimentKey], n: int | None,
                       seed: int) -> list[ExperimentKey]:
    """``n`` of ``keys`` drawn without replacement (all if ``n`` is None or larger), in the
    order of ``keys``. Seeded and nested: a larger sample holds every smaller one."""
    if n is None or n >= len(keys):
        return list(keys)
    rng = np.random.default_rng(derive_seed(seed, "oracle-sample"))
    picked = set(rng.permutation(len(keys))[:max(0, n)].tolist())
    return [k for i, k in enumerate(keys) if i in picked]


@dataclass
class OracleRun:
    """What :func:`run_oracle` did."""

    rows: list[OracleRow]
    """The oracle rows of the sample (old and new)."""
    ran: int
    failures: list[Failure]
    running_s: float


def run_oracle(spec: CampaignSpec, out: Path, map_paths: dict[str, str],
               records: dict[tuple[str, int, int], InstanceRecord], *, executor: Executor,
               workers: int = 1, step_ms: float = DEFAULT_STEP_MS, sample: int | None = None,
               progress: Progress | None = None, clairvoyant: bool = False) -> OracleRun:
    """Sweep the oracle of the campaign's experiments (or a seeded sample of ``sample`` of
    them) into ``OUT/oracle.csv`` (the clairvoyant: ``OUT/clairvoyant.csv``, progress phase
    ``clairvoyant``); rows already there with the same step are reused."""
    keys = [(m, n, i, s) for m, n, i in spec.slots() for s in spec.experiment_seeds(m, n, i)]
    chosen = sample_experiments(keys, sample, spec.seed)
    phase = "clairvoyant" if clairvoyant else "oracle"
    path = out / f"{phase}.csv"
    try:
        old = {r.key: r for r in read_oracle_rows(path) if r.step_ms == step_ms}
    except ValueError as exc:
        raise CampaignError(str(exc)) from None
    write_oracle_rows(path, old.values(), append=False)
    tasks = [OracleTask(map_paths[m], records[(m, n, i)], s, spec.sim, step_ms, clairvoyant)
             for m, n, i, s in chosen if (m, n, i, s) not in old]
    tasks.sort(key=lambda t: -t.record.agents)  # the longest first
    report = progress or (lambda _phase, _done, _total: None)
    done = len(chosen) - len(tasks)
    report(phase, done, len(chosen))
    failures: list[Failure] = []
    began = time.perf_counter()
    size = max(1, min(4, len(tasks) // (workers * 8)))
    for got in run_chunks(executor, run_oracle_chunk, chunked(tasks, size), 2 * workers):
        rows = [r for r in got if isinstance(r, OracleRow)]
        failures.extend(r for r in got if isinstance(r, Failure))
        write_oracle_rows(path, rows, append=True)
        old.update((r.key, r) for r in rows)
        done += len(got)
        report(phase, done, len(chosen))
    mine = [old[k] for k in chosen if k in old]
    write_oracle_rows(path, mine, append=False)
    return OracleRun(mine, len(tasks), failures, round(time.perf_counter() - began, 3))
