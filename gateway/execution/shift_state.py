"""The state of a lifelong shift as plain data (sans-I/O): a snapshot, and a restore.

A journaled shift grows with every robot report, tick and segment; a snapshot sums up what
those inputs built, so the journal can replace them by one record (the gateway's compaction,
:mod:`gateway.server.shift_journal`). :func:`snapshot_shift` reads the state of a
:class:`~gateway.execution.lifelong.LifelongExecutor` (its live ADG, errand book and task pool
included) into a :class:`ShiftState`, made of frozen dataclasses of ints, floats, strings and
lists only (JSON-able: the journal validates and writes it with pydantic; no pickle).
:func:`restore_shift` gives a fresh executor of the same configuration that state, field by
field, so that it then behaves as the live one on the same inputs.

What is state and what is configuration: the grid, the fleet's size, the scheduler, the
durations, the planning period and window, the lookahead and the pool's task list, reveal and
``keep`` come from the configuration (the restoring executor is built with them); everything
the inputs change is here: each robot's cell, heading and action counter, its dispatched and
unfinished actions, the unfinished tail of the live ADG with its Type 2 dependencies and the
cells' last leavers, the monitor's slack baseline (Δ0) and next check, the errand book's plan
view and markers, every kept task with its state and times, the pool's queues, kept events and
idempotency keys, and the counters (planner calls, segments, triggers, errands done, tasks
finished, the outstanding planner call). The container's order is kept where behaviour or the
task API depends on it (dicts in insertion order, the backlog's heap as a list).

:data:`SNAPSHOT_VERSION` is written into each snapshot; a restore refuses any other.
"""

from __future__ import annotations

import math
from collections import OrderedDict, deque
from dataclasses import dataclass

from gateway.execution.errors import ExecutionError
from gateway.execution.lifelong import LifelongExecutor, LifelongMode, PlanRequest
from gateway.execution.live_adg import LiveAction
from gateway.execution.tasks import NewTask, Task, TaskEvent, TaskPool, TaskState

SNAPSHOT_VERSION = 1
"""The layout of :class:`ShiftState` (a snapshot of another version is refused)."""

ActionRow = tuple[int, int, int, int, int, int]
"""A committed action: kind, cell, heading, dependency robot, dependency seq, append order."""
EventRow = tuple[int, int, TaskState, int, int, float]
"""A task event: seq, task, state, robot, errands done, time."""
NewTaskRow = tuple[list[int], int, float | None]
"""One task of a submission: errands, priority, deadline."""


@dataclass(frozen=True)
class TaskSnapshot:
    """One kept task (every field of :class:`~gateway.execution.tasks.Task`)."""

    id: int
    errands: list[int]
    release_tick: int
    robot: int
    done: int
    finish_tick: float
    length: int
    priority: int
    deadline: float | None
    key: str | None
    state: TaskState
    submitted: float
    assigned_at: float
    errand_at: list[float]
    cancelled_at: float
    listed: bool
    announced: int


@dataclass(frozen=True)
class PoolSnapshot:
    """The task pool: its kept tasks (in the book's order) and, by id in their order, where
    each waits; its events, keys and counters."""

    book: list[TaskSnapshot]
    tasks: list[int]
    open: list[int]
    waiting: list[int]
    paused: list[int]
    ended: list[int]
    released: list[int]
    backlog: list[tuple[int, float | None, int]]
    """The backlog heap as a list: -priority, deadline (None: none), task id."""
    keys: list[tuple[str, list[NewTaskRow], list[int]]]
    """Idempotency keys (oldest first): the submission and the ids it made."""
    events: list[EventRow]
    event_seq: int
    finished: int
    next_id: int
    listed: int
    now: float


@dataclass(frozen=True)
class RequestSnapshot:
    """The planner call outstanding (a :class:`~gateway.execution.lifelong.PlanRequest`)."""

    call: int
    starts: list[int]
    goals: list[list[int]]
    hold: list[int]
    avoid: list[int]
    steps: int


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


def snapshot_shift(ex: LifelongExecutor) -> ShiftState:
    """The state of ``ex`` (commands it emitted and the driver did not drain yet are output,
    not state: a driver snapshots after routing them)."""
    adg, book = ex.adg, ex.book
    req = ex.outstanding
    leaver_r, leaver_s = adg._leaver_robot, adg._leaver_seq
    return ShiftState(
        version=SNAPSHOT_VERSION, robots=ex.n, mode=ex.mode.value, paused=ex.paused,
        now_ms=ex._now, threshold_ms=ex.threshold_ms, cell=list(ex.cell),
        heading=list(ex.heading), sent=list(ex._sent), started_at=list(ex._started_at),
        blocked=list(ex._blocked), refusing=list(ex._refusing),
        waiters=[sorted(w) for w in ex._waiters],
        segment_of=[list(s) for s in ex._segment_of], completion=list(ex.completion),
        end_cell=list(adg.end_cell), end_heading=list(adg.end_heading),
        queue=[[(a.kind, a.cell, a.heading, a.dep_robot, a.dep_seq, a.order) for a in q]
               for q in adg.queue],
        done=list(adg.done), appended=list(adg.appended),
        leavers=[(c, r, leaver_s[c]) for c, r in enumerate(leaver_r) if r >= 0],
        order=adg._order, slack0=[list(s) for s in ex._slack0], slack_based=ex._slack_based,
        fleet_slack_ms=ex.fleet_slack_ms, next_call_ms=ex._next_call,
        next_check_ms=ex._next_check, calls=ex.calls, segments=ex.segments,
        outstanding=None if req is None else RequestSnapshot(
            req.call, list(req.starts), [list(g) for g in req.goals], list(req.hold),
            list(req.avoid), req.steps),
        triggers=ex.triggers, errands_done=ex.errands_done, plan_task=list(book.plan_task),
        plan_idx=list(book.plan_idx), markers=[list(m) for m in book.markers],
        pool=_pool_snapshot(ex.pool))


def _pool_snapshot(pool: TaskPool) -> PoolSnapshot:
    return PoolSnapshot(
        book=[_task_snapshot(t) for t in pool.book.values()], tasks=list(pool.tasks),
        open=list(pool.open), waiting=list(pool._waiting), paused=list(pool._paused),
        ended=list(pool._ended), released=list(pool._released),
        backlog=[(-p, None if math.isinf(d) else d, i) for (p, d), i in pool._backlog],
        keys=[(key, [(list(t.errands), t.priority, t.deadline) for t in new], list(ids))
              for key, (new, ids) in pool._keys.items()],
        events=[(e.seq, e.task, e.state, e.robot, e.done, e.t) for e in pool.events],
        event_seq=pool.event_seq, finished=pool.finished, next_id=pool.next_id,
        listed=pool._listed, now=pool.now)


def _task_snapshot(t: Task) -> TaskSnapshot:
    return TaskSnapshot(
        t.id, list(t.errands), t.release_tick, t.robot, t.done, t.finish_tick, t.length,
        t.priority, t.deadline, t.key, t.state, t.submitted, t.assigned_at, list(t.errand_at),
        t.cancelled_at, t.listed, t.announced)


def restore_shift(ex: LifelongExecutor, state: ShiftState) -> None:
    """Give ``ex`` (fresh: built with the shift's configuration, not started) the state
    ``state``; ExecutionError (one line) if the snapshot does not fit it."""
    if state.version != SNAPSHOT_VERSION:
        raise ExecutionError(f"a shift snapshot of version {state.version} cannot be restored "
                             f"(this gateway writes version {SNAPSHOT_VERSION})")
    if ex.mode is not LifelongMode.NEW:
        raise ExecutionError("a snapshot is restored into a shift not started yet")
    if state.robots != ex.n or len(state.end_cell) != ex.n:
        raise ExecutionError(f"the snapshot is of a shift of {state.robots} robots, the "
                             f"configuration has {ex.n}")
    adg, book, n = ex.adg, ex.book, ex.n
    ex.mode = LifelongMode(state.mode)
    ex.paused, ex._now, ex.threshold_ms = state.paused, state.now_ms, state.threshold_ms
    ex.cell, ex.heading = list(state.cell), list(state.heading)
    ex._sent, ex._started_at = list(state.sent), list(state.started_at)
    ex._blocked, ex._refusing = bytearray(state.blocked), bytearray(state.refusing)
    ex._waiters = [set(w) for w in state.waiters]
    ex._segment_of = [deque((f, s) for f, s in seg) for seg in state.segment_of]
    ex.completion = list(state.completion)
    adg.end_cell, adg.end_heading = list(state.end_cell), list(state.end_heading)
    adg.queue = [deque(LiveAction(*row) for row in q) for q in state.queue]
    adg.done, adg.appended = list(state.done), list(state.appended)
    adg._leaver_robot = [-1] * adg.grid.size
    adg._leaver_seq = [0] * adg.grid.size
    for c, r, s in state.leavers:
        adg._leaver_robot[c], adg._leaver_seq[c] = r, s
    adg._order = state.order
    ex._slack0 = [deque(s) for s in state.slack0]
    ex._slack_based, ex.fleet_slack_ms = state.slack_based, state.fleet_slack_ms
    ex._next_call, ex._next_check = state.next_call_ms, state.next_check_ms
    ex.calls, ex.segments = state.calls, state.segments
    req = state.outstanding
    ex.outstanding = None if req is None else PlanRequest(
        req.call, tuple(req.starts), tuple(tuple(g) for g in req.goals), tuple(req.hold),
        tuple(req.avoid), req.steps)
    ex.triggers, ex.errands_done = state.triggers, state.errands_done
    book.plan_task, book.plan_idx = list(state.plan_task), list(state.plan_idx)
    book.markers = [deque((c, t) for c, t in m) for m in state.markers]
    if len(book.markers) != n:
        raise ExecutionError("the snapshot's errand book does not fit the fleet")
    _restore_pool(ex.pool, state.pool)


def _restore_pool(pool: TaskPool, snap: PoolSnapshot) -> None:
    book = {t.id: Task(
        t.id, tuple(t.errands), t.release_tick, t.robot, t.done, t.finish_tick, t.length,
        t.priority, t.deadline, t.key, t.state, t.submitted, t.assigned_at, list(t.errand_at),
        t.cancelled_at, t.listed, t.announced) for t in snap.book}
    pool.book = book
    pool.tasks = {i: book[i] for i in snap.tasks}
    pool.open = {i: book[i] for i in snap.open}
    pool._waiting = {i: book[i] for i in snap.waiting}
    pool._paused = {i: book[i] for i in snap.paused}
    pool._ended = OrderedDict((i, book[i]) for i in snap.ended)
    pool._released = dict.fromkeys(snap.released)
    pool._backlog = [((-p, math.inf if d is None else d), i) for p, d, i in snap.backlog]
    pool._keys = OrderedDict(
        (key, (tuple(NewTask(tuple(e), p, d) for e, p, d in new), list(ids)))
        for key, new, ids in snap.keys)
    pool.events = deque((TaskEvent(*e) for e in snap.events), maxlen=pool.keep)
    pool.event_seq, pool.finished, pool.next_id = snap.event_seq, snap.finished, snap.next_id
    pool._listed, pool.now = snap.listed, snap.now
