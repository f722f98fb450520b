"""Journaling the executor's inputs, and replaying them to rebuild it after a crash.

:class:`JournaledExecutor` is the engine's executor: each input (a robot report, a tick, a
pause, a replan request, a plan) is handed to its journal sink before it is applied. The
executor is deterministic, so :func:`replay` of those records through a fresh one rebuilds it,
its monitor and policy included, field by field; it hands the commands the executor gives on
the way (dispatches, cancels, a solve request, completion) and the reports it took to the
caller, which rebuilds its robot sessions from them. No I/O here, no clock.

A journal compacted at a plan boundary starts with a snapshot instead of the run
(:func:`snapshot_of` writes it when a plan is adopted): the replay then starts the executor
with the adopted plan from the state the snapshot carries (:meth:`Executor.start_adopted`),
which is the state the records it replaced would have rebuilt.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass, field
from functools import partial
from typing import Any

from gateway.execution.actions import ActionDurations
from gateway.execution.commands import Command, SolveRequest
from gateway.execution.errors import ExecutionError
from gateway.execution.oneshot.blocks import BlockTracker
from gateway.execution.oneshot.executor import Executor
from gateway.execution.oneshot.policies import SlackReplan, make_policy
from gateway.execution.trace_records import Record, intruder_record
from gateway.planning.grid import Cell
from gateway.planning.plan import Plan
from gateway.runtime.journal import (
    REJECTED,
    AdoptRecord,
    EncodedReport,
    ExecutorEvent,
    IntruderRecord,
    JournalError,
    JournalRecord,
    PolicyRecord,
    RejectedRecord,
    ReportRecord,
    RunRecord,
    ShadowRecord,
    SnapshotRecord,
    SpeedRecord,
    TimeRecord,
    report_json,
)

Sink = Callable[[Any], None]
"""Where a journaled executor hands its input records (a journal's ``append``)."""


def plan_of(paths: Sequence[Sequence[Cell]], headings: Sequence[Sequence[int]] | None) -> Plan:
    """The plan of journaled paths (and headings)."""
    cells = tuple(tuple((int(x), int(y)) for x, y in p) for p in paths)
    return Plan(cells, None if headings is None else tuple(tuple(h) for h in headings))


class JournaledReports:
    """Mixin of a journaled executor (one-shot or lifelong; listed before it in the bases):
    every robot report, tick, pause and resume is handed to :attr:`sink` before the executor
    applies it."""

    sink: Sink | None = None
    _record: Callable[[Record], None] | None

    def set_record(self, record: Callable[[Record], None] | None) -> None:
        """Where trace records go from now on (a resumed run's trace)."""
        self._record = record

    def journaled(self, record: Any, apply: Callable[..., Any], *args: Any) -> Any:
        """Hand ``record`` to :attr:`sink` (if journaled), then ``apply(*args)``. A refusal
        (:class:`ExecutionError`: nothing changed) is journaled right after it (``rejected``),
        so replay refuses that input again and accepts every other one."""
        sink = self.sink
        if sink is None:
            return apply(*args)
        sink(record)
        try:
            return apply(*args)
        except ExecutionError:
            sink(REJECTED)
            raise

    def _report(self, apply: Callable[..., None], event: ExecutorEvent, robot: int, plan: int,
                action: int, now_ms: float, *reason: str) -> None:
        """Journal, then apply, a robot report (the record is built only if journaled: the hot
        path of a big fleet)."""
        record: EncodedReport | ReportRecord | None = None
        if self.sink is not None:
            why = reason[0] if reason else ""
            body = report_json(event, robot, plan, action, now_ms, why)
            record = EncodedReport(body) if body is not None else ReportRecord.model_construct(
                event=event, robot=robot, plan=plan, index=action, t_ms=now_ms, reason=why)
        self.journaled(record, apply, robot, plan, action, now_ms, *reason)

    def started(self, robot: int, plan: int, action: int, now_ms: float) -> None:
        """Journal, then apply, a robot's ``started``."""
        self._report(super().started, "started", robot, plan, action, now_ms)  # type: ignore[misc]

    def finished(self, robot: int, plan: int, action: int, now_ms: float) -> None:
        """Journal, then apply, a robot's ``finished``."""
        self._report(super().finished, "finished", robot, plan, action,  # type: ignore[misc]
                     now_ms)

    def blocked(self, robot: int, plan: int, action: int, now_ms: float) -> None:
        """Journal, then apply, a robot's ``blocked`` before it starts."""
        self._report(super().blocked, "blocked", robot, plan, action, now_ms)  # type: ignore[misc]

    def stopped(self, robot: int, plan: int, action: int, now_ms: float) -> None:
        """Journal, then apply, a robot's ``blocked`` on the way."""
        self._report(super().stopped, "stopped", robot, plan, action, now_ms)  # type: ignore[misc]

    def unblocked(self, robot: int, plan: int, action: int, now_ms: float) -> None:
        """Journal, then apply, a robot's ``unblocked``."""
        self._report(super().unblocked, "unblocked", robot, plan, action,  # type: ignore[misc]
                     now_ms)

    def cancelled(self, robot: int, plan: int, action: int, now_ms: float) -> None:
        """Journal, then apply, a robot's ``cancelled``."""
        self._report(super().cancelled, "cancelled", robot, plan, action,  # type: ignore[misc]
                     now_ms)

    def refused(self, robot: int, plan: int, action: int, now_ms: float,
                reason: str = "") -> None:
        """Journal, then apply, a robot's refusal."""
        self._report(super().refused, "refused", robot, plan, action,  # type: ignore[misc]
                     now_ms, reason)

    def journal_time(self, kind: str, apply: Callable[[float], Any], now_ms: float) -> None:
        """Journal a time input of ``kind`` (a tick, pause, resume, ...), then apply it."""
        record = None if self.sink is None else TimeRecord.model_construct(kind=kind, t_ms=now_ms)
        self.journaled(record, apply, now_ms)

    def tick(self, now_ms: float) -> None:
        """Journal, then apply, a monitor tick."""
        self.journal_time("tick", super().tick, now_ms)  # type: ignore[misc]

    def pause(self, now_ms: float) -> None:
        """Journal, then apply, the operator's pause."""
        self.journal_time("pause", super().pause, now_ms)  # type: ignore[misc]

    def resume(self, now_ms: float) -> None:
        """Journal, then apply, the operator's resume."""
        self.journal_time("resume", super().resume, now_ms)  # type: ignore[misc]

    def replay_common(self, rec: JournalRecord,
                      on_report: Callable[[ReportRecord], None]) -> bool:
        """Apply a journaled robot report, tick, pause or resume, which every executor takes
        alike (a report is then passed to ``on_report``); False for any other record."""
        match rec:
            case ReportRecord(event="refused"):
                self.refused(rec.robot, rec.plan, rec.index, rec.t_ms, rec.reason)
            case ReportRecord():
                getattr(self, rec.event)(rec.robot, rec.plan, rec.index, rec.t_ms)
            case TimeRecord(kind="tick" | "pause" | "resume"):
                getattr(self, rec.kind)(rec.t_ms)
            case _:
                return False
        if isinstance(rec, ReportRecord):
            on_report(rec)
        return True


class JournaledExecutor(JournaledReports, Executor):
    """An :class:`Executor` that hands every input to ``sink`` before applying it."""

    def __init__(self, plan: Plan, *, sink: Sink | None = None, **kwargs: Any) -> None:
        super().__init__(plan, **kwargs)
        self.sink = sink

    def request_replan(self, now_ms: float) -> None:
        self.journal_time("replan", super().request_replan, now_ms)

    def abandon_replan(self, now_ms: float) -> None:
        self.journal_time("abandon", super().abandon_replan, now_ms)

    def adopt_plan(self, plan: Plan, now_ms: float, solver_ms: float = 0.0) -> None:
        """Adopt ``plan``; ``solver_ms`` is the run's solver time charged so far."""
        self.journaled(AdoptRecord(
            t_ms=now_ms, paths=[list(p) for p in plan.paths], solver_ms=solver_ms,
            headings=None if plan.headings is None else [list(h) for h in plan.headings]),
            super().adopt_plan, plan, now_ms)

    def shadow_solved(self, plan: Plan | None, now_ms: float) -> bool:
        return bool(self.journaled(ShadowRecord(
            t_ms=now_ms, paths=None if plan is None else [list(p) for p in plan.paths],
            headings=None if plan is None or plan.headings is None
            else [list(h) for h in plan.headings]), super().shadow_solved, plan, now_ms))

    def set_policy(self, rec: PolicyRecord) -> None:
        """The operator's policy (``rec.replace``) or slack threshold, journaled."""
        if self.sink is not None:
            self.sink(rec)
        if rec.replace:
            self.policy = make_policy(rec.policy, seed=rec.policy_seed,
                                      threshold_ms=rec.threshold_ms,
                                      makespan_lb_ms=rec.makespan_lb_ms)
        elif isinstance(self.policy, SlackReplan):
            self.policy.threshold_ms = rec.threshold_ms


def executor_for(run: RunRecord, sink: Sink | None = None,
                 record: Callable[[Record], None] | None = None) -> JournaledExecutor:
    """A fresh executor for ``run`` (not started)."""
    return JournaledExecutor(
        plan_of(run.paths, run.headings), sink=sink,
        policy=make_policy(run.policy, seed=run.policy_seed, threshold_ms=run.threshold_ms,
                           makespan_lb_ms=run.makespan_lb_ms),
        action_ms=run.action_ms, drop_waits=run.drop_waits, max_replans=run.max_replans,
        record=record, lookahead=run.lookahead,
        durations=[ActionDurations(m, t, w) for m, t, w in run.durations],
        block_history=run.block_history)


@dataclass
class Carried:
    """What the engine keeps besides the executor, journaled in a snapshot."""

    policy: str
    policy_seed: int
    threshold_ms: float
    speed: float
    solver_ms: float
    intruders: set[Cell]
    replan_marks: list[dict[str, Any]]
    trace_lines: int


def snapshot_of(run: RunRecord, ex: JournaledExecutor, carried: Carried) -> SnapshotRecord:
    """The snapshot of a run that has just adopted its current plan (nothing else happened
    since): it replaces the run's records in the journal."""
    plan = ex.plan
    blocks = ex.blocks
    return SnapshotRecord(
        run=run, plan_id=ex.plan_id, t_ms=ex.now_ms, paths=[list(p) for p in plan.paths],
        headings=None if plan.headings is None else [list(h) for h in plan.headings],
        solver_ms=carried.solver_ms, completions_ms=list(ex.completions_ms),
        replans=ex.replans, paused=ex.paused,
        blocks_open=[(c, since, blocks.seen[c]) for c, since in blocks.open.items()],
        blocks_history=list(blocks.history), policy=carried.policy,
        policy_seed=carried.policy_seed, threshold_ms=carried.threshold_ms,
        policy_state=dict(vars(ex.policy)), speed=carried.speed,
        intruders=sorted(carried.intruders), replan_marks=carried.replan_marks,
        trace_lines=carried.trace_lines)


@dataclass
class Replayed:
    """What a replay rebuilt besides the robot sessions."""

    run: RunRecord
    executor: JournaledExecutor
    policy: str
    policy_seed: int
    threshold_ms: float
    speed: float
    solver_ms: float = 0.0
    intruders: set[Cell] = field(default_factory=set)
    last_t_ms: float = 0.0
    solve: SolveRequest | None = None
    """The solver request still unanswered (the replan must be solved again)."""
    shadow: SolveRequest | None = None
    """The latest shadow solve request (solved again if still unanswered)."""
    records: int = 0
    replan_marks: list[dict[str, Any]] = field(default_factory=list)
    """The replans before the snapshot the journal starts with (none without one)."""
    trace_lines: int = 0
    """Trace records the run wrote before the replayed ones (the snapshot's)."""


def _from_snapshot(snap: SnapshotRecord, trace: Callable[[Record], None] | None
                   ) -> Replayed:
    """The executor a snapshot describes, started with its plan."""
    run = snap.run.model_copy(update={
        "paths": snap.paths, "headings": snap.headings, "policy": snap.policy,
        "policy_seed": snap.policy_seed, "threshold_ms": snap.threshold_ms})
    ex = executor_for(run, record=trace)
    vars(ex.policy).update(snap.policy_state)
    ex.blocks = BlockTracker(
        min_ms=ex.blocks.min_ms, open={(c[0], c[1]): since for c, since, _ in snap.blocks_open},
        seen={(c[0], c[1]): seen for c, _, seen in snap.blocks_open},
        history=list(snap.blocks_history))
    ex.start_adopted(snap.plan_id, snap.t_ms, completions_ms=snap.completions_ms,
                     replans=snap.replans, paused=snap.paused)
    return Replayed(snap.run, ex, snap.policy, snap.policy_seed, snap.threshold_ms, snap.speed,
                    solver_ms=snap.solver_ms, intruders={(c[0], c[1]) for c in snap.intruders},
                    last_t_ms=snap.t_ms, records=1,
                    replan_marks=[dict(m) for m in snap.replan_marks],
                    trace_lines=snap.trace_lines)


def replay(records: Iterable[JournalRecord], *,
           on_commands: Callable[[list[Command]], None],
           on_report: Callable[[ReportRecord], None],
           trace: Callable[[Record], None] | None = None,
           on_snapshot: Callable[[Replayed], None] | None = None) -> Replayed | None:
    """Rebuild the journaled run (None if there is none): its executor, started (from the run
    or from the snapshot the journal starts with) and fed every record in order.
    ``on_snapshot`` gets what a snapshot restored before anything is replayed,
    ``on_commands`` what the executor commands after each record, ``on_report`` every report
    it accepted (a report it refused live is refused again), ``trace`` the run's trace
    records. JournalError if the journal is not a run's."""
    it = iter(records)
    first = next(it, None)
    if first is None:
        return None
    if isinstance(first, SnapshotRecord):
        out = _from_snapshot(first, trace)
        if on_snapshot is not None:
            on_snapshot(out)
    elif isinstance(first, RunRecord):
        ex = executor_for(first, record=trace)
        out = Replayed(first, ex, first.policy, first.policy_seed, first.threshold_ms,
                       first.speed, records=1)
        ex.start(0.0)
    else:
        raise JournalError(f"the journal starts with a {first.kind} record, not a run")
    ex = out.executor
    _commands(ex, out, on_commands)
    for number, rec, rejected in inputs(list(it), 2):
        out.records = number + rejected
        t = getattr(rec, "t_ms", None)
        if t is not None:
            out.last_t_ms = max(out.last_t_ms, t)
        as_live(number, rec, rejected, partial(_apply, ex, out, rec, on_report, trace))
        _commands(ex, out, on_commands)
    return out


def inputs(records: Sequence[JournalRecord], first: int
           ) -> Iterator[tuple[int, JournalRecord, bool]]:
    """``(number, record, rejected)`` for each of ``records`` (the journal's from record number
    ``first`` on), a ``rejected`` record folded into the input before it: that input was
    refused live. JournalError for one that follows no input."""
    i = 0
    while i < len(records):
        rec = records[i]
        if isinstance(rec, RejectedRecord):
            raise JournalError(f"record {first + i} of the journal is damaged (a refusal that "
                               f"follows no input): start with --fresh to abandon the run")
        rejected = i + 1 < len(records) and isinstance(records[i + 1], RejectedRecord)
        yield first + i, rec, rejected
        i += 1 + rejected


def as_live(number: int, rec: JournalRecord, rejected: bool, apply: Callable[[], object]
            ) -> None:
    """Apply the journal's record ``number`` as it was applied live: accepted again, or refused
    again (``rejected``: nothing changes). JournalError naming it if replay decides otherwise:
    the journal does not hold what happened (an edited record whose checksum was recomputed,
    or a fleetgate that decides otherwise), and the state it would rebuild is not the one the
    robots and clients were told of."""
    try:
        apply()
    except ExecutionError as exc:
        if rejected:
            return
        raise JournalError(f"record {number} of the journal does not replay: its {rec.kind} "
                           f"was accepted, but replay refuses it ({exc}): start with --fresh "
                           f"to abandon the run") from None
    if rejected:
        raise JournalError(f"record {number} of the journal does not replay: its {rec.kind} "
                           f"was refused, but replay accepts it: start with --fresh to "
                           f"abandon the run")


def _commands(ex: Executor, out: Replayed, on_commands: Callable[[list[Command]], None]
              ) -> None:
    commands = ex.drain()
    for c in commands:
        if isinstance(c, SolveRequest) and c.shadow:
            out.shadow = c
        elif isinstance(c, SolveRequest):
            out.solve = c
    if commands:
        on_commands(commands)


def _apply(ex: JournaledExecutor, out: Replayed, rec: JournalRecord,
           on_report: Callable[[ReportRecord], None],
           trace: Callable[[Record], None] | None) -> None:
    if ex.replay_common(rec, on_report):
        return
    match rec:
        case TimeRecord(kind="replan"):
            ex.request_replan(rec.t_ms)
        case TimeRecord(kind="abandon"):
            out.solve = None
            ex.abandon_replan(rec.t_ms)
        case AdoptRecord():
            out.solve = None
            out.solver_ms = rec.solver_ms
            ex.adopt_plan(plan_of(rec.paths, rec.headings), rec.t_ms)
        case ShadowRecord():
            ex.shadow_solved(None if rec.paths is None else plan_of(rec.paths, rec.headings),
                             rec.t_ms)
        case PolicyRecord():
            if rec.replace:
                out.policy, out.policy_seed = rec.policy, rec.policy_seed
            out.threshold_ms = rec.threshold_ms
            ex.set_policy(rec)
        case IntruderRecord():
            cell = (rec.cell[0], rec.cell[1])
            if rec.state == "on":
                out.intruders.add(cell)
            else:
                out.intruders.discard(cell)
            if trace is not None:
                trace(intruder_record(rec.t_ms, cell, rec.state))
        case SpeedRecord():
            out.speed = rec.speed
        case RunRecord() | SnapshotRecord():
            raise JournalError(f"a {rec.kind} record after the journal's first")
