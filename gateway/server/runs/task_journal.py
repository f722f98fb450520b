"""Durable tasks: the task book's changes go to the gateway's journal, and a restarted gateway
rebuilds the book from them.

:class:`TaskJournal` appends a :class:`~gateway.runtime.journal.TaskRecord` for every event of
the pool not journaled yet; the engine calls :meth:`TaskJournal.flush` just before each
commit (``Engine.before_commit``), and the owner task commits before it yields, so a task is
on disk before the answer that accepts it leaves, and before any event stream or robot hears
of a change. :func:`restore_tasks` applies the journaled records to a fresh pool of the same
shift (:meth:`~gateway.execution.lifelong.tasks.TaskPool.restore`): no accepted task is lost, a
finished one stays finished (it cannot finish again), a started one stays with its robot, and
event numbers go on where they stopped (an event stream resumes with its ``Last-Event-ID``).
"""

from __future__ import annotations

import logging
from collections.abc import Iterable
from functools import partial
from typing import TYPE_CHECKING

from gateway.execution.lifelong.shift_state import HistoryLog
from gateway.execution.lifelong.tasks import NewTask, TaskEvent, TaskPool
from gateway.runtime.journal import (
    Journal,
    JournalError,
    JournalRecord,
    ShiftHistoryRecord,
    ShiftRecord,
    ShiftSnapshotRecord,
    TaskRecord,
)
from gateway.server.runs.shift_journal import compact_shift, resume_shift

if TYPE_CHECKING:
    from gateway.server.engine import Engine

log = logging.getLogger("fleetgate.tasks")


class TaskJournal:
    """Journals the events of ``pool`` (from the first one it has not journaled)."""

    def __init__(self, pool: TaskPool, journal: Journal, after: int = 0) -> None:
        self.pool = pool
        self.journal = journal
        self.after = after
        """The last event journaled."""

    def flush(self) -> None:
        """Append the pool's new events to the journal (the engine commits them next)."""
        pool = self.pool
        if pool.event_seq == self.after:
            return
        events, complete = pool.events_after(self.after)
        if not complete:  # more than ``pool.keep`` events in one owner step
            log.error("task events were dropped before they were journaled",
                      extra={"after": self.after, "first": events[0].seq if events else None})
        for e in events:
            rec = TaskRecord.model_construct(
                seq=e.seq, task=e.task, state=e.state, robot=e.robot, done=e.done, t_ms=e.t,
                errands=None, priority=0, deadline_ms=None, key=None, listed=False)
            if e.state == "queued":
                task = pool.book.get(e.task)
                if task is not None:
                    rec = TaskRecord(seq=e.seq, task=e.task, state=e.state, robot=e.robot,
                                     done=e.done, t_ms=e.t, errands=list(task.errands),
                                     priority=task.priority, deadline_ms=task.deadline,
                                     key=task.key, listed=task.listed,
                                     batch=task.batch if task.batch >= 0 else None)
            self.journal.append(rec)
        self.after = pool.event_seq


def restore_tasks(pool: TaskPool, records: Iterable[JournalRecord], now: float) -> int:
    """Rebuild ``pool`` from the journaled task records; returns the last one's ``seq``."""
    n = 0
    for rec in records:
        if not isinstance(rec, TaskRecord):
            continue
        new = None if rec.errands is None else NewTask(tuple(rec.errands), rec.priority,
                                                        rec.deadline_ms)
        pool.restore(TaskEvent(rec.seq, rec.task, rec.state, rec.robot, rec.done, rec.t_ms),
                     new, rec.key, rec.listed, -1 if rec.batch is None else rec.batch)
        n = rec.seq
    pool.restored(now)
    return n


def journal_tasks(engine: Engine) -> bool:
    """Journal the engine's shift from now on (its task book, and its executor's inputs), after
    rebuilding it from the journal (True if there was something to rebuild): a journaled
    shift is replayed and goes on (:func:`~gateway.server.runs.shift_journal.resume_shift`); task
    records alone (tasks submitted before a shift started, or a journal of a gateway that
    journaled only its tasks) rebuild the book. A journaled one-shot run is a
    :class:`JournalError` (``--fresh`` abandons it)."""
    pool, journal, run = engine.tasks, engine.journal, engine.lifelong
    assert pool is not None and journal is not None and run is not None
    records = list(journal.records())
    if records and not isinstance(records[0], TaskRecord | ShiftRecord | ShiftSnapshotRecord
                                                | ShiftHistoryRecord):
        raise JournalError(f"the journal {journal.path} holds a one-shot run and the gateway "
                           f"is in lifelong mode: start with --fresh to abandon it")
    last = 0
    history = HistoryLog()
    if any(isinstance(rec, ShiftRecord | ShiftSnapshotRecord) for rec in records):
        history = HistoryLog(resume_shift(engine, records).history)
        last = pool.event_seq
    elif records:
        last = restore_tasks(pool, records, pool.now)
        run.executor.book.adopt()  # robots go on with their started tasks
        log.info("task book rebuilt from the journal", extra={
            "records": len(records), "tasks": len(pool.book), "finished": pool.finished})
    tasks = TaskJournal(pool, journal, last)
    run.counted_until(last)
    engine.before_commit.append(tasks.flush)

    def sink(rec: JournalRecord) -> None:
        tasks.flush()  # the task changes before the input first: the replay's order
        journal.append(rec)

    run.executor.sink = sink
    assert engine.config.lifelong is not None
    run.after_adopt = partial(compact_shift, engine, history,
                              engine.config.lifelong.snapshot_segments)
    return bool(records)
