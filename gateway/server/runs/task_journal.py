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

from gateway.execution.lifelong.tasks import NewTask, TaskEvent, TaskPool
from gateway.runtime.journal import (
    Journal,
    JournalRecord,
    TaskRecord,
)

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
