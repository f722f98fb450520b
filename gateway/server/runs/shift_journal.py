"""Durable lifelong shifts: the shift executor's inputs journaled, and replayed after a restart.

:class:`JournaledLifelong` is the shift's executor in a gateway with a journal: every input
(a robot report, a monitor tick, pause, resume, stop, the operator's "plan now", an adopted
segment, a failed planner call, a new slack threshold) is handed to its sink before it is
applied. The sink first appends the task book's events not journaled yet (so a task change
made by the task API is journaled before the next executor input, in the order it happened),
then the input. The executor and the task book are deterministic and read no clock, so
:func:`replay_shift` of the records through a fresh executor of the same configuration
rebuilds both, field by field: the live ADG, every robot's cell and action counter, the
segment counter, the planner call outstanding, the task assignments and errand progress.
Task events the replayed executor makes again are checked against the journaled ones (a
difference is a :class:`~gateway.runtime.journal.JournalError`); the others are the task API's
changes (a submission, a cancel, a pause, a resume), applied again at their time.

The planner's output is journaled (a :class:`~gateway.runtime.journal.SegmentRecord`), not
recomputed: it runs off the owner task, and when it answers is part of the input. A call still
outstanding when the gateway died is planned again after the replay (its answer never left
the process). :func:`resume_shift` wires a replay into the engine: run id, robot sessions
(which learn what was dispatched and reported, so reconnecting robots are re-synchronised by
their ``hello``), the trace file, the clock. No I/O here but the engine's.

Compaction: every ``snapshot_segments`` adopted segments :func:`compact_shift` replaces the
journal's records by one :class:`~gateway.runtime.journal.ShiftSnapshotRecord` (the shift's
state, :mod:`gateway.execution.lifelong.shift_state`, and what the engine keeps besides). A journal
that starts with one is replayed by restoring the snapshot into the fresh executor, then
feeding it the records after it; the robot sessions learn the executor's dispatched,
unfinished actions from the executor itself.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from functools import partial
from typing import Any, Protocol

from gateway.execution.errors import ExecutionError
from gateway.execution.lifelong.executor import (
    LifelongCommand,
    LifelongExecutor,
    LifelongMode,
    PlanRequest,
    Segment,
)
from gateway.execution.lifelong.shift_state import (
    HistoryLog,
    ShiftHistory,
    restore_shift,
    snapshot_shift,
)
from gateway.execution.lifelong.tasks import NewTask, TaskEvent, TaskPool
from gateway.runtime.journal import (
    ExecutorEvent,
    Journal,
    JournalError,
    JournalRecord,
    ReportRecord,
    SegmentRecord,
    ShiftHistoryRecord,
    ShiftRecord,
    ShiftSnapshotRecord,
    SpeedRecord,
    TaskRecord,
    ThresholdRecord,
    TimeRecord,
)
from gateway.runtime.trace import trace_line
from gateway.server.runs.base import RunContext
from gateway.server.runs.resume import JournaledReports, as_live, inputs

log = logging.getLogger("fleetgate.lifelong")


class JournaledLifelong(JournaledReports, LifelongExecutor):
    """A :class:`LifelongExecutor` that hands every input to :attr:`sink` before applying it
    (None: not journaled, e.g. while it is being replayed)."""

    def stop(self, now_ms: float) -> None:
        self.journal_time("stop", super().stop, now_ms)

    def plan_now(self, now_ms: float) -> None:
        self.journal_time("replan", super().plan_now, now_ms)

    def plan_failed(self, call: int, now_ms: float) -> None:
        self.journal_time("abandon", partial(super().plan_failed, call), now_ms)

    def adopt(self, segment: Segment, now_ms: float) -> None:
        self.journaled(None if self.sink is None else SegmentRecord(
            call=segment.call, t_ms=now_ms, states=[list(s) for s in segment.states],
            reached=[list(r) for r in segment.reached],
            priorities=list(segment.priorities)), super().adopt, segment, now_ms)

    def set_threshold(self, threshold_ms: float) -> None:
        """The operator's slack threshold."""
        if self.sink is not None:
            self.sink(ThresholdRecord(threshold_ms=threshold_ms))
        self.threshold_ms = threshold_ms


@dataclass
class ShiftReplayed:
    """What a replay rebuilt besides the executor and the robot sessions."""

    shift: ShiftRecord | None = None
    """The shift's start (None: the journal holds task changes made before it started)."""
    speed: float | None = None
    """The clock speed set last during the shift (None: the shift's start speed)."""
    threshold_ms: float | None = None
    """The slack threshold the operator set last (None: never in the journal)."""
    snapshot: ShiftSnapshotRecord | None = None
    """The snapshot the journal starts with, if it is compacted."""
    history: list[ShiftHistory] = field(default_factory=list)
    """The chunks of task history before the snapshot."""
    last_t_ms: float = 0.0
    records: int = 0


def replay_shift(records: Sequence[JournalRecord], ex: JournaledLifelong, *,
                 on_commands: Callable[[list[LifelongCommand]], None],
                 on_report: Callable[[ReportRecord], None],
                 on_start: Callable[[ShiftRecord], None],
                 on_snapshot: Callable[[ShiftSnapshotRecord], None] | None = None
                 ) -> ShiftReplayed:
    """Feed the journaled shift to ``ex`` (fresh, of the shift's configuration, not
    journaling): ``on_start`` gets the shift's start before the executor starts (or is
    restored from the snapshot the journal starts with; ``on_snapshot`` then gets the snapshot
    once it is restored), ``on_commands`` what the executor commands after each record
    (planner requests included: the caller decides what to do with them), ``on_report`` every
    report it accepted (one it refused live is refused again). JournalError if the task events
    do not follow or the snapshot does not fit ``ex``."""
    out = ShiftReplayed()
    pool = ex.pool
    i = 0
    while i < len(records) and isinstance(chunk := records[i], ShiftHistoryRecord):
        out.history.append(chunk.history)
        i += 1
    if i < len(records) and isinstance(snap := records[i], ShiftSnapshotRecord):
        i += 1
        out.shift, out.speed, out.threshold_ms = snap.shift, snap.speed, snap.threshold_ms
        out.snapshot, out.last_t_ms = snap, snap.state.now_ms
        on_start(snap.shift)
        try:
            restore_shift(ex, snap.state, out.history)
        except ExecutionError as exc:
            raise JournalError(f"the journal's shift snapshot: {exc}") from None
        if on_snapshot is not None:
            on_snapshot(snap)
    elif out.history:
        raise JournalError("the journal holds a shift's task history but no snapshot after it")
    out.records = i
    while i < len(records):
        rec = records[i]
        t = getattr(rec, "t_ms", None)
        if t is not None:
            out.last_t_ms = max(out.last_t_ms, t)
        if isinstance(rec, TaskRecord):
            i = _task_change(pool, records, i)
            out.records = i
            continue
        number, rec, rejected = next(inputs(records[i:i + 2], i + 1))
        i = out.records = number + rejected
        try:
            as_live(number, rec, rejected, partial(_apply, ex, out, rec, on_report, on_start))
        except JournalError:
            raise
        except Exception:  # an internal error live too (the engine logged it and went on)
            log.exception("replaying a %s record raised, as it did live", rec.kind)
        commands = ex.drain()
        if commands:
            on_commands(commands)
    return out


def _apply(ex: JournaledLifelong, out: ShiftReplayed, rec: JournalRecord,
           on_report: Callable[[ReportRecord], None],
           on_start: Callable[[ShiftRecord], None]) -> None:
    if ex.replay_common(rec, on_report):
        return
    match rec:
        case ShiftRecord():
            out.shift = rec
            on_start(rec)
            ex.start(0.0)
        case TimeRecord(kind="stop"):
            ex.stop(rec.t_ms)
        case TimeRecord(kind="replan"):
            ex.plan_now(rec.t_ms)
        case TimeRecord(kind="abandon"):
            req = ex.outstanding
            if req is None:
                raise JournalError("a failed planner call is journaled, but none is outstanding")
            ex.plan_failed(req.call, rec.t_ms)
        case SegmentRecord():
            ex.adopt(Segment(rec.call, rec.states, rec.reached, rec.priorities), rec.t_ms)
        case ThresholdRecord():
            out.threshold_ms = rec.threshold_ms
            ex.set_threshold(rec.threshold_ms)
        case SpeedRecord():
            out.speed = rec.speed
        case _:
            raise JournalError(f"a {rec.kind} record in a lifelong shift's journal")


def _task_change(pool: TaskPool, records: Sequence[JournalRecord], i: int) -> int:
    """Replay the task record ``records[i]`` (and the rest of its submission); returns the
    index of the next record. A record of an event the pool made again is checked; any other
    is a change of the task API (submit, cancel, pause, resume), made again."""
    rec = records[i]
    assert isinstance(rec, TaskRecord)
    if rec.seq <= pool.event_seq:
        _check(pool, rec)
        return i + 1
    task = pool.book.get(rec.task)
    end = i + 1
    if rec.state == "queued" and task is None and rec.errands is not None \
            and rec.task == pool.next_id and not rec.listed:
        new = [NewTask(tuple(rec.errands), rec.priority, rec.deadline_ms)]
        while end < len(records):
            nxt = records[end]
            if not (isinstance(nxt, TaskRecord) and nxt.state == "queued"
                    and nxt.errands is not None and nxt.task == rec.task + len(new)
                    and nxt.key == rec.key and nxt.t_ms == rec.t_ms and not nxt.listed
                    and nxt.seq == rec.seq + len(new) and nxt.batch == rec.batch):
                break
            new.append(NewTask(tuple(nxt.errands), nxt.priority, nxt.deadline_ms))
            end += 1
        pool.submit(new, rec.t_ms, rec.key)
    elif rec.state == "cancelled" and task is not None:
        pool.cancel(rec.task, rec.t_ms)
    elif rec.state == "paused" and task is not None:
        pool.pause(rec.task, rec.t_ms)
    elif rec.state == "queued" and task is not None and task.state == "paused":
        pool.resume(rec.task, rec.t_ms)
    else:
        raise JournalError(f"task event {rec.seq} ({rec.state} task {rec.task}) does not "
                           "follow from the journal")
    for k in range(i, end):
        _check(pool, records[k])
    return end


def _check(pool: TaskPool, rec: JournalRecord) -> None:
    """The pool made the journaled event ``rec`` again: the same one (JournalError if not)."""
    assert isinstance(rec, TaskRecord)
    events, _ = pool.events_after(rec.seq - 1)
    if not events or events[0].seq != rec.seq:
        return  # dropped from the pool's window already (``keep``): nothing to compare
    want = TaskEvent(rec.seq, rec.task, rec.state, rec.robot, rec.done, rec.t_ms)
    if events[0] != want:
        raise JournalError(f"task event {rec.seq} replayed as {events[0]}, journaled as "
                           f"{want}")


class ShiftRun(Protocol):
    """What the journal wiring needs of a shift run (:class:`~.lifelong.LifelongRun`)."""

    executor: JournaledLifelong
    started: ShiftRecord | None

    def plan_window(self, req: PlanRequest) -> None:
        """Have the planner answer ``req``."""


def resume_shift(engine: RunContext, run: ShiftRun, records: Sequence[JournalRecord]
                 ) -> ShiftReplayed:
    """Replay the journaled shift into the engine's fresh one and carry on: same run id,
    the clock continued, robot sessions rebuilt, the trace completed, an outstanding planner
    call planned again."""
    ex = run.executor
    trace: list[str] = []

    def record(rec: dict[str, object]) -> None:
        engine.feed.record(rec)
        trace.append(trace_line(rec))

    def start(rec: ShiftRecord) -> None:
        engine.run_id = rec.run_id
        engine.runs += 1

    def commands(cs: list[LifelongCommand]) -> None:
        engine.route([c for c in cs if not isinstance(c, PlanRequest)])

    def restored(snap: ShiftSnapshotRecord) -> None:
        """The robot sessions learn what the restored executor has dispatched (and which of
        those actions are under way), as a replay of the records would have told them."""
        engine.feed.replan_marks = [dict(m) for m in snap.replan_marks]
        for r in range(ex.n):
            held = ex.dispatched(r)
            engine.route(list(held))
            started, blocked = ex.head_state(r)
            events: list[ExecutorEvent] = ["started"] * started
            events += ["stopped" if started else "blocked"] * blocked
            for event in events:
                engine.replayed_report(ReportRecord(
                    event=event, robot=r, plan=held[0].plan, index=held[0].action,
                    t_ms=ex.now_ms))

    ex.set_record(record)
    engine.replayed_trace = trace  # a stopped shift's summary record goes there too
    engine.replaying = True
    try:
        done = replay_shift(records, ex, on_commands=commands,
                            on_report=engine.replayed_report, on_start=start,
                            on_snapshot=restored)
    finally:
        engine.replaying = False
        ex.set_record(engine.feed.record)
    if done.shift is None:
        return done
    run.started = done.shift
    engine.feed.resume_trace(trace, 0 if done.snapshot is None else done.snapshot.trace_lines)
    if done.threshold_ms is not None:
        engine.threshold_ms = done.threshold_ms
    speed = done.speed if done.speed is not None else done.shift.speed
    engine.clock.set_speed(speed)
    away = (engine.clock.wall_s() - done.shift.wall_start_s) * 1000.0 * speed
    engine.clock.reset(max(done.last_t_ms, away))
    engine.paused = ex.paused
    if ex.outstanding is not None:  # its answer was never journaled: plan it again
        run.plan_window(ex.outstanding)
    log.info("resumed the journaled shift", extra={
        "run": engine.run_id, "records": done.records, "segments": ex.segments,
        "t_ms": round(engine.clock.now_ms()), "finished_tasks": ex.finished_tasks})
    engine.status_changed()
    return done


def compact_shift(engine: RunContext, run: ShiftRun, history: HistoryLog, every: int) -> None:
    """After an adopted segment (between two owner-task items): every ``every`` segments
    (0: never) of a running shift, replace the journal's records by a snapshot of the shift.
    What is buffered is committed and the trace flushed first, then one transaction deletes
    the records and writes the snapshot: a crash before it leaves the records, one after it
    the snapshot, and both replay to the same shift."""
    journal = engine.journal
    assert journal is not None
    if not compaction_due(run.executor, every) or run.started is None:
        return
    engine.commit()
    feed = engine.feed
    compact_journal(journal, history, run.executor, shift=run.started,
                    speed=engine.clock.speed, threshold_ms=engine.threshold_ms,
                    replan_marks=feed.replan_marks, trace_lines=feed.trace_lines)


def compact_journal(journal: Journal, history: HistoryLog, ex: LifelongExecutor,
                    **carried: Any) -> None:
    """Replace ``journal``'s records by a snapshot of ``ex`` (``carried``: the other fields
    of :class:`~gateway.runtime.journal.ShiftSnapshotRecord`), in one transaction that keeps
    the chunks of task history the pool may still need and writes the new chunk first."""
    chunk, drop = history.next(ex.pool)
    journal.compact_shift(ShiftSnapshotRecord(state=snapshot_shift(ex), **carried),
                          None if chunk is None else ShiftHistoryRecord(history=chunk), drop)


def compaction_due(ex: LifelongExecutor, every: int) -> bool:
    """Whether a shift that has just adopted a segment is compacted now: every ``every``
    segments (0: never), while it runs (a stopping shift's end is left to its records)."""
    return every > 0 and ex.segments % every == 0 and ex.mode is LifelongMode.RUNNING
