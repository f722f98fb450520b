"""The state of a lifelong shift as plain data (sans-I/O): a snapshot, and a restore.

A journaled shift grows with every robot report, tick and segment; a snapshot sums up what
those inputs built, so the journal can replace them by one record (the gateway's compaction,
:mod:`gateway.server.runs.shift_journal`). :func:`snapshot_shift` reads the state of a
:class:`~gateway.execution.lifelong.executor.LifelongExecutor` (its live ADG, errand book and task
pool
included) into a :class:`ShiftState`, made of frozen dataclasses of ints, floats, strings and
lists only (JSON-able: the journal validates and writes it with pydantic; no pickle).
:func:`restore_shift` gives a fresh executor of the same configuration that state, field by
field, so that it then behaves as the live one on the same inputs. Each part takes and
restores its own state (``LifelongExecutor.snapshot``/``restore``, ``LiveADG``'s,
``TaskPool.snapshot``/``restore_snapshot``); this module only lays them out as one record.

What the task pool keeps for the task API that never changes once made (tasks that ended,
events, idempotency keys: up to ``keep`` of each, so hours of a shift) is not in the snapshot:
it goes to the journal in chunks (:class:`ShiftHistory`), each holding only what is new since
the previous one (:class:`HistoryLog`), so a snapshot's size and cost follow the live state,
not the shift's length; a restore replays the chunks the journal holds.

What is state and what is configuration: the grid, the fleet's size, the scheduler, the
durations, the planning period and window, the lookahead and the pool's task list, reveal and
``keep`` come from the configuration (the restoring executor is built with them); everything
the inputs change is here: each robot's cell, heading and action counter, its dispatched and
unfinished actions, the unfinished tail of the live ADG with its Type 2 dependencies and the
cells' last leavers, the monitor's slack baseline (Δ0) and next check, the errand book's plan
view and markers, every task not ended with its state and times, the pool's queues, and the
counters (planner calls, segments, triggers, errands done, tasks finished, the outstanding
planner call). The container's order is kept where behaviour or the
task API depends on it (dicts in insertion order, the backlog's heap as a list).

:data:`SNAPSHOT_VERSION` is written into each snapshot; a restore refuses any other.
"""

from __future__ import annotations

from collections import OrderedDict, deque
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field, fields
from operator import attrgetter
from typing import Any

from gateway.execution.errors import ExecutionError
from gateway.execution.lifelong.executor import LifelongExecutor, LifelongMode, PlanRequest
from gateway.execution.lifelong.tasks import NewTask, Task, TaskEvent, TaskPool, TaskState

SNAPSHOT_VERSION = 3
"""The layout of :class:`ShiftState` (a snapshot of another version is refused)."""

ActionRow = tuple[int, int, int, int, int, int]
"""A committed action: kind, cell, heading, dependency robot, dependency seq, append order."""
NewTaskRow = tuple[list[int], int, float | None]
"""One task of a submission: errands, priority, deadline."""


@dataclass(frozen=True)
class TaskColumns:
    """Kept tasks column by column, in the book's order (task k is entry k of every list):
    every field of :class:`~gateway.execution.lifelong.tasks.Task`. A long shift keeps up to
    ``keep``
    ended tasks; lists of plain values encode and validate several times faster than an
    object per task."""

    id: list[int]
    errands: list[tuple[int, ...]]
    release_tick: list[int]
    robot: list[int]
    done: list[int]
    finish_tick: list[float]
    length: list[int]
    priority: list[int]
    deadline: list[float | None]
    key: list[str | None]
    state: list[TaskState]
    submitted: list[float]
    assigned_at: list[float]
    errand_at: list[list[float]]
    cancelled_at: list[float]
    listed: list[bool]
    announced: list[int]
    batch: list[int]
    waited: list[float]
    queued_at: list[float]


@dataclass(frozen=True)
class EventColumns:
    """Kept task events column by column, oldest first (every field of
    :class:`~gateway.execution.lifelong.tasks.TaskEvent`)."""

    seq: list[int]
    task: list[int]
    state: list[TaskState]
    robot: list[int]
    done: list[int]
    t: list[float]


@dataclass(frozen=True)
class ShiftHistory:
    """A chunk of what a task pool keeps that never changes once made: tasks that ended (in
    the order they ended), events, and idempotency keys with their submission (in the order
    they were used), each since the previous chunk (:class:`HistoryLog`). The pool keeps the
    latest ``keep`` of each; a restore replays the chunks in order and keeps as many."""

    ended: TaskColumns
    events: EventColumns
    keys: list[tuple[str, list[NewTaskRow], list[int]]]


@dataclass(frozen=True)
class PoolSnapshot:
    """The task pool without its history (:class:`ShiftHistory`): its tasks not ended (in
    the book's order) and, by id in their order, where each waits; its counters."""

    live: TaskColumns
    tasks: list[int]
    open: list[int]
    waiting: list[int]
    paused: list[int]
    released: list[int]
    backlog: list[tuple[int, float | None, int]]
    """The backlog heap as a list: -priority, deadline (None: none), task id."""
    event_seq: int
    finished: int
    next_id: int
    listed: int
    now: float


@dataclass(frozen=True)
class RequestSnapshot:
    """The planner call outstanding (a
    :class:`~gateway.execution.lifelong.executor.PlanRequest`)."""

    call: int
    starts: list[int]
    goals: list[list[int]]
    hold: list[int]
    avoid: list[int]
    steps: int
    priorities: list[int] = field(default_factory=list)


@dataclass(frozen=True)
class ShiftState:
    """Everything the inputs of a lifelong shift built (see the module doc)."""

    version: int
    robots: int
    mode: str
    paused: bool
    now_ms: float
    threshold_ms: float | None
    # robots
    cell: list[int]
    heading: list[int]
    sent: list[int]
    started_at: list[float]
    blocked: list[int]
    refusing: list[int]
    waiters: list[list[int]]
    segment_of: list[list[tuple[int, int]]]
    completion: list[float]
    # the live ADG
    end_cell: list[int]
    end_heading: list[int]
    queue: list[list[ActionRow]]
    done: list[int]
    appended: list[int]
    leavers: list[tuple[int, int, int]]
    """Cells with a last leaver: cell, robot, its action's seq."""
    order: int
    # monitor and planning
    slack0: list[list[float]]
    slack_based: bool
    fleet_slack_ms: float
    next_call_ms: float
    next_check_ms: float
    calls: int
    segments: int
    outstanding: RequestSnapshot | None
    triggers: int
    errands_done: int
    # the errand book and the task pool
    plan_task: list[int]
    plan_idx: list[int]
    markers: list[list[tuple[int, int]]]
    pool: PoolSnapshot
    priorities: list[int] = field(default_factory=list)
    """PIBT's priorities after the latest adopted segment (empty in a snapshot written
    before they were kept: the shift's planner then starts them afresh)."""


def snapshot_shift(ex: LifelongExecutor) -> ShiftState:
    """The state of ``ex`` (commands it emitted and the driver did not drain yet are output,
    not state: a driver snapshots after routing them): each part snapshots itself."""
    book, req = ex.book, ex.outstanding
    return ShiftState(
        version=SNAPSHOT_VERSION, robots=ex.n, **ex.snapshot(), **ex.adg.snapshot(),
        outstanding=None if req is None else RequestSnapshot(
            req.call, list(req.starts), [list(g) for g in req.goals], list(req.hold),
            list(req.avoid), req.steps, list(req.priorities)),
        plan_task=list(book.plan_task), plan_idx=list(book.plan_idx),
        markers=[list(m) for m in book.markers], pool=_pool_snapshot(ex.pool))


_TASK_FIELDS = tuple(f.name for f in fields(Task))
_EVENT_FIELDS = tuple(f.name for f in fields(TaskEvent))


def _columns(items: Iterable[Any], names: Sequence[str]) -> dict[str, list[Any]]:
    """``{field: [its value in each item]}``."""
    rows = list(items)
    return {name: list(map(attrgetter(name), rows)) for name in names}


def _rows(columns: Any, names: Sequence[str]) -> Iterator[tuple[Any, ...]]:
    """Each item's values in field order (the inverse of :func:`_columns`)."""
    return zip(*(getattr(columns, name) for name in names), strict=True)


def _task_columns(tasks: Iterable[Task]) -> TaskColumns:
    cols = _columns(tasks, _TASK_FIELDS)
    cols["errand_at"] = list(map(list, cols["errand_at"]))  # a live task appends to it
    return TaskColumns(**cols)


def _tasks(cols: TaskColumns) -> Iterator[Task]:
    for row in _rows(cols, _TASK_FIELDS):
        task = Task(*row)
        task.errands, task.errand_at = tuple(task.errands), list(task.errand_at)
        yield task


def _pool_snapshot(pool: TaskPool) -> PoolSnapshot:
    state = pool.snapshot()
    return PoolSnapshot(live=_task_columns(state.pop("live")), **state)


class HistoryLog:
    """The chunks of a task pool's history (:class:`ShiftHistory`) that a journal holds,
    oldest first: :meth:`next` makes the chunk of what the pool kept since the last one and
    says how many of the oldest chunks it no longer needs (the pool dropped every task, event
    and key of theirs). ``chunks``: those the journal holds already (after a restart)."""

    def __init__(self, chunks: Sequence[ShiftHistory] = ()) -> None:
        self._last: list[tuple[int | None, int | None, str | None]] = []
        # per chunk: its last event seq, ended task and key (None: it has none)
        self._seq = 0  # the last event, ended task and key of any chunk
        self._task: int | None = None
        self._key: str | None = None
        for chunk in chunks:
            self._add(chunk)

    def _add(self, chunk: ShiftHistory) -> None:
        last = (chunk.events.seq[-1] if chunk.events.seq else None,
                chunk.ended.id[-1] if chunk.ended.id else None,
                chunk.keys[-1][0] if chunk.keys else None)
        self._last.append(last)
        seq, task, key = last
        self._seq = self._seq if seq is None else seq
        self._task = self._task if task is None else task
        self._key = self._key if key is None else key

    def next(self, pool: TaskPool) -> tuple[ShiftHistory | None, int]:
        """The pool's history since the last chunk (None: nothing new), and how many of the
        oldest chunks (this one excluded) are no longer needed."""
        events = list(_newest(pool.events, lambda e: e.seq > self._seq))
        ended = _after(pool.ended, self._task)
        keys = _after(pool.submissions, self._key)
        chunk = None
        if events or ended or keys:
            chunk = ShiftHistory(
                _task_columns(pool.ended[i] for i in ended),
                EventColumns(**_columns(events, _EVENT_FIELDS)),
                [(key, [(list(t.errands), t.priority, t.deadline)
                        for t in pool.submissions[key][0]],
                  list(pool.submissions[key][1])) for key in keys])
            self._add(chunk)
        first = pool.events[0].seq if pool.events else pool.event_seq + 1
        drop = 0
        for seq, task, key in self._last[:-1]:
            if (seq is not None and seq >= first) or task in pool.ended \
                    or key in pool.submissions:
                break
            drop += 1
        del self._last[:drop]
        return chunk, drop


def _newest(items: Sequence[Any], new: Callable[[Any], bool]) -> Iterator[Any]:
    """The items at the end of ``items`` for which ``new`` holds, in order."""
    k = len(items)
    while k > 0 and new(items[k - 1]):
        k -= 1
    return (items[i] for i in range(k, len(items)))


def _after(kept: Mapping[Any, Any], last: Any) -> list[Any]:
    """The keys of ``kept`` after ``last`` (all of them if ``last`` is not there)."""
    out = []
    for key in reversed(kept):
        if key == last:
            break
        out.append(key)
    out.reverse()
    return out


def restore_shift(ex: LifelongExecutor, state: ShiftState,
                  history: Sequence[ShiftHistory] = ()) -> None:
    """Give ``ex`` (fresh: built with the shift's configuration, not started) the state
    ``state`` and its pool's ``history`` (every chunk since the shift's start that the pool
    may still keep, in order); ExecutionError (one line) if the snapshot does not fit it."""
    if state.version != SNAPSHOT_VERSION:
        raise ExecutionError(f"a shift snapshot of version {state.version} cannot be restored "
                             f"(this gateway writes version {SNAPSHOT_VERSION})")
    if ex.mode is not LifelongMode.NEW:
        raise ExecutionError("a snapshot is restored into a shift not started yet")
    if state.robots != ex.n or len(state.end_cell) != ex.n:
        raise ExecutionError(f"the snapshot is of a shift of {state.robots} robots, the "
                             f"configuration has {ex.n}")
    if len(state.markers) != ex.n:
        raise ExecutionError("the snapshot's errand book does not fit the fleet")
    req = state.outstanding
    ex.restore(**{name: getattr(state, name) for name in _EXECUTOR_FIELDS},
               outstanding=None if req is None else PlanRequest(
                   req.call, tuple(req.starts), tuple(tuple(g) for g in req.goals),
                   tuple(req.hold), tuple(req.avoid), req.steps, tuple(req.priorities)))
    ex.adg.restore(**{name: getattr(state, name) for name in _ADG_FIELDS})
    book = ex.book
    book.plan_task, book.plan_idx = list(state.plan_task), list(state.plan_idx)
    book.markers = [deque((c, t) for c, t in m) for m in state.markers]
    _restore_pool(ex.pool, state.pool, history)


_ADG_FIELDS = ("end_cell", "end_heading", "queue", "done", "appended", "leavers", "order")
_EXECUTOR_FIELDS = ("mode", "paused", "now_ms", "threshold_ms", "cell", "heading", "sent",
                    "started_at", "blocked", "refusing", "waiters", "segment_of",
                    "completion", "slack0", "slack_based", "fleet_slack_ms", "next_call_ms",
                    "next_check_ms", "calls", "segments", "triggers", "errands_done",
                    "priorities")


def _restore_pool(pool: TaskPool, snap: PoolSnapshot,
                  history: Sequence[ShiftHistory]) -> None:
    keep = pool.keep
    ended: OrderedDict[int, Task] = OrderedDict()
    keys: OrderedDict[str, tuple[tuple[NewTask, ...], list[int]]] = OrderedDict()
    events: deque[TaskEvent] = deque(maxlen=keep)
    for chunk in history:  # made as the pool made them: the latest ``keep`` of each stay
        for task in _tasks(chunk.ended):
            ended[task.id] = task
            if len(ended) > keep:
                ended.popitem(last=False)
        for key, new, ids in chunk.keys:
            keys.pop(key, None)
            keys[key] = (tuple(NewTask(tuple(e), p, d) for e, p, d in new), list(ids))
            if len(keys) > keep:
                keys.popitem(last=False)
        events.extend(TaskEvent(*e) for e in _rows(chunk.events, _EVENT_FIELDS))
    pool.restore_snapshot(
        _tasks(snap.live), ended=ended, keys=keys, events=events, tasks=snap.tasks,
        open=snap.open, waiting=snap.waiting, paused=snap.paused, released=snap.released,
        backlog=snap.backlog, event_seq=snap.event_seq, finished=snap.finished,
        next_id=snap.next_id, listed=snap.listed, now=snap.now)
