"""Lifelong tasks: the task book, its pool of revealed tasks and pluggable schedulers (pure, no
I/O, no clock: every time is passed in, in the driver's unit: ticks or ms).

A task is an ordered list of errand cells (flat ids); a robot completes an errand by arriving
at its cell, and the task when its last errand is done. Tasks come from two places:

* a task list (LoRR): the pool keeps ``reveal`` tasks revealed and unfinished (LoRR's
  ``numTasksReveal`` x team size): each finished task reveals the next one of the list, which
  is cycled when it runs out (task ids keep growing);
* submissions (a warehouse system): :meth:`TaskPool.submit` takes one task or a batch, with a
  priority and a deadline, under an idempotency key (a retried submission returns the same
  task ids and creates nothing). Submitted tasks wait in a backlog, most urgent first, and are
  revealed before list tasks when a slot frees; a submission more urgent than a revealed open
  task takes its slot.

A task's state (:data:`TaskState`) is ``queued`` (waiting, revealed or not), ``paused`` (by an
operator: never assigned while paused), ``assigned`` (to a robot, no errand done), ``started``
(``done`` errands done), ``finished`` or ``cancelled``. A task not started yet (no errand done)
can be cancelled or paused; either takes it from its robot, which finds it gone from
:attr:`TaskPool.tasks` (its plan view drops it; an errand it still reaches is ignored).

Fairness: with a bound ``max_wait``, a task costs the schedulers less the longer it has waited
without a robot (aging, from half the bound on), and one that has waited the whole bound goes
before every task of its priority that has not (:meth:`TaskPool.rank`) and its robot keeps it,
so a far or long task is not passed over forever by nearer, shorter ones;
:meth:`TaskPool.waits` and :func:`wait_percentiles` measure how long tasks wait for a robot.

Every change of state is an event (:class:`TaskEvent`: sequence number, task, state, robot,
errands done, time) in :attr:`TaskPool.events`, the ordered stream an API serves; a task
released and given back to the same robot in one scheduling round (reassignment) makes no
event. Events, ended tasks and idempotency keys are kept up to bounds (``keep``), so a shift's
memory stays bounded.
"""

from __future__ import annotations

import heapq
import math
from collections import OrderedDict, deque
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from itertools import pairwise
from typing import Any, Literal, Protocol

import numpy as np
import numpy.typing as npt

from gateway.execution.lifelong.matching_kernel import greedy_groups

TaskState = Literal["queued", "paused", "assigned", "started", "finished", "cancelled"]
"""Where a task is (see the module doc)."""
TASK_STATES: tuple[TaskState, ...] = ("queued", "paused", "assigned", "started", "finished",
                                      "cancelled")
KEEP = 100_000
"""Default bound on kept events, ended tasks and idempotency keys."""


class TaskError(ValueError):
    """A task request is refused; the message says why."""


class TaskNotFound(TaskError):
    """No such task (never submitted, or ended long ago and no longer kept)."""


class TaskConflict(TaskError):
    """The request conflicts with the task book: an idempotency key reused for a different
    request, or a task in a state that does not allow it (e.g. cancelling a started task)."""


@dataclass
class Task:
    """A task: its errands, who does it (-1: nobody yet), how many errands are done, and the
    times of its changes (in the pool's time unit; -1: not yet)."""

    id: int
    errands: tuple[int, ...]
    release_tick: int
    """When it was revealed to the schedulers (whole time units, as LoRR's output wants)."""
    robot: int = -1
    done: int = 0
    finish_tick: float = -1
    length: int = -1  # estimated moves from its first errand to its last (-1: not yet known)
    priority: int = 0
    """Higher first."""
    deadline: float | None = None
    """Earlier first among equal priorities (None: none)."""
    key: str | None = None
    """The idempotency key it was submitted under."""
    state: TaskState = "queued"
    submitted: float = -1
    assigned_at: float = -1
    errand_at: list[float] = field(default_factory=list)
    """When each errand was done."""
    cancelled_at: float = -1
    listed: bool = False
    """Made from the task list (else submitted)."""
    announced: int = -1  # the robot the last event named
    batch: int = -1
    """The id of the first task of its submission (-1: made from the task list)."""
    waited: float = 0.0
    """Time it spent queued without a robot before its present spell (see ``queued_at``)."""
    queued_at: float = -1
    """Since when it is queued without a robot (-1: it has one, or is paused or ended); set
    from ``submitted`` when it is made."""

    def __post_init__(self) -> None:
        if self.queued_at < 0 and self.state == "queued":
            self.queued_at = self.submitted

    @property
    def urgency(self) -> tuple[int, float]:
        """Sort key of the schedulers and the backlog: higher priority, then earlier deadline."""
        return -self.priority, math.inf if self.deadline is None else self.deadline


@dataclass(frozen=True)
class NewTask:
    """One task of a submission."""

    errands: tuple[int, ...]
    priority: int = 0
    deadline: float | None = None


@dataclass(frozen=True, slots=True)
class TaskEvent:
    """A change of a task's state: ``done`` errands done, on ``robot`` (-1: none) at ``t``."""

    seq: int
    task: int
    state: TaskState
    robot: int
    done: int
    t: float


@dataclass
class TaskPool:
    """The task book: revealed tasks of a task list and submitted ones; ``tasks`` are the
    revealed, unfinished ones (by id), ``open`` those of them nobody does (the schedulers'
    choice). See the module doc."""

    task_list: Sequence[tuple[int, ...]]
    reveal: int
    leg: Callable[[int, int], int] | None = None  # estimated moves between two cells
    tasks: dict[int, Task] = field(default_factory=dict)
    open: dict[int, Task] = field(default_factory=dict)
    finished: int = 0
    next_id: int = 0
    keep: int = KEEP
    """How many events, ended tasks and idempotency keys are kept."""
    max_wait: float | None = None
    """The fairness bound (pool time units): an open task that has waited this long since it
    was submitted goes before every task of its priority that has not (:meth:`rank`; None: no
    bound, a far or long task may wait as long as nearer ones keep coming)."""
    station_cap: int | None = None
    """At most this many robots at a time are sent to one first-errand cell (a station's
    queue, :meth:`offered`; None: no bound)."""
    book: dict[int, Task] = field(default_factory=dict)
    """Every kept task by id (in id order): queued, paused, under way and ended."""
    events: deque[TaskEvent] = field(init=False)
    """The latest ``keep`` events, in order (:meth:`events_after` reads them)."""
    event_seq: int = 0
    """Sequence number of the next event (events are numbered from 1)."""
    now: float = 0
    """The latest time the pool was given."""
    _listed: int = 0  # list tasks revealed so far
    _backlog: list[tuple[tuple[int, float], int]] = field(default_factory=list)
    _waiting: dict[int, Task] = field(default_factory=dict)  # queued, not revealed
    _paused: dict[int, Task] = field(default_factory=dict)
    _ended: OrderedDict[int, Task] = field(default_factory=OrderedDict)
    _keys: OrderedDict[str, tuple[tuple[NewTask, ...], list[int]]] = field(
        default_factory=OrderedDict)
    _released: dict[int, None] = field(default_factory=dict)  # released, event not yet made

    def __post_init__(self) -> None:
        if any(not t for t in self.task_list):
            raise ValueError("a task pool needs tasks with at least one errand each")
        if self.reveal <= 0:
            raise ValueError("a task pool must reveal at least one task")
        self.events = deque(maxlen=self.keep)
        self.top_up(0)

    # ------------------------------------------------------------------ snapshot
    @property
    def ended(self) -> Mapping[int, Task]:
        """The kept tasks that ended (finished or cancelled), in the order they ended."""
        return self._ended

    @property
    def submissions(self) -> Mapping[str, tuple[tuple[NewTask, ...], list[int]]]:
        """The kept idempotency keys, in the order they were used: the submission and the
        ids it made."""
        return self._keys

    def snapshot(self) -> dict[str, Any]:
        """The pool's state without its history (a shift snapshot): the tasks not ended (in
        the book's order), by id where each waits, the backlog heap as a list
        ``(-priority, deadline or None, id)``, and the counters."""
        ended = self._ended
        return {
            "live": [t for i, t in self.book.items() if i not in ended],
            "tasks": list(self.tasks), "open": list(self.open), "waiting": list(self._waiting),
            "paused": list(self._paused), "released": list(self._released),
            "backlog": [(-p, None if math.isinf(d) else d, i) for (p, d), i in self._backlog],
            "event_seq": self.event_seq, "finished": self.finished, "next_id": self.next_id,
            "listed": self._listed, "now": self.now}

    def restore_snapshot(self, live: Iterable[Task], *, ended: OrderedDict[int, Task],
                         keys: OrderedDict[str, tuple[tuple[NewTask, ...], list[int]]],
                         events: Iterable[TaskEvent], tasks: Sequence[int],
                         open: Sequence[int], waiting: Sequence[int], paused: Sequence[int],
                         released: Sequence[int],
                         backlog: Sequence[tuple[int, float | None, int]], event_seq: int,
                         finished: int, next_id: int, listed: int, now: float) -> None:
        """Take the state :meth:`snapshot` gave, with the history replayed from the journal
        (``ended``, ``keys``, ``events``: the latest ``keep`` of each)."""
        book = {t.id: t for t in live}
        book.update(ended)
        self.book = {i: book[i] for i in sorted(book)}  # the book is in id order
        self.tasks = {i: book[i] for i in tasks}
        self.open = {i: book[i] for i in open}
        self._waiting = {i: book[i] for i in waiting}
        self._paused = {i: book[i] for i in paused}
        self._ended = ended
        self._released = dict.fromkeys(released)
        self._backlog = [((-p, math.inf if d is None else d), i) for p, d, i in backlog]
        self._keys = keys
        self.events = deque(events, maxlen=self.keep)
        self.event_seq, self.finished, self.next_id = event_seq, finished, next_id
        self._listed, self.now = listed, now

    # ------------------------------------------------------------------ revealing
    def top_up(self, tick: float) -> None:
        """Reveal tasks until ``reveal`` are revealed and unfinished: submitted ones first
        (most urgent first), then the next ones of the task list."""
        self.settle(tick)
        while len(self.tasks) < self.reveal:
            if self._backlog:
                _, task_id = heapq.heappop(self._backlog)
                task = self._waiting.pop(task_id, None)
                if task is None:
                    continue  # paused or cancelled meanwhile
                task.release_tick = int(tick)
            elif self.task_list:
                errands = tuple(self.task_list[self._listed % len(self.task_list)])
                self._listed += 1
                task = Task(self.next_id, errands, int(tick), submitted=tick, listed=True)
                self.next_id += 1
                self.book[task.id] = task
                self._event(task, tick)
            else:
                return
            self.tasks[task.id] = task
            self.open[task.id] = task

    def _rebalance(self, now: float) -> None:
        """Reveal what fits; then a waiting task more urgent than a revealed open one takes
        its slot (the open one waits again)."""
        self.top_up(now)
        while self._backlog and self.open:
            first = self._waiting.get(self._backlog[0][1])
            if first is None:
                heapq.heappop(self._backlog)
                continue
            worst = max(self.open.values(), key=lambda t: (t.urgency, t.id))
            if first.urgency >= worst.urgency:
                return
            del self.tasks[worst.id], self.open[worst.id]
            self._wait(worst)
            self.top_up(now)

    def _wait(self, task: Task) -> None:
        self._waiting[task.id] = task
        heapq.heappush(self._backlog, (task.urgency, task.id))

    # ------------------------------------------------------------------ the schedulers' side
    def offered(self) -> npt.NDArray[np.int64]:
        """The ids of the open tasks the schedulers may hand out: all of them, or with a
        :attr:`station_cap`, per first-errand cell as many as the cap leaves beside the
        robots already on their way there (assigned, no errand done), the first by
        :meth:`rank`, then the shorter (:meth:`length`). On the LoRR 2024 warehouse_large
        (10,000 robots, 15,000 revealed tasks from 352 emitter cells on the map's edges)
        every robot was sent to an emitter at once and the crowds there jammed: 137 tasks in
        600 ticks under the 2026 rules, 591 with a cap of 12, 1,075 with 4."""
        if self.station_cap is None:
            return np.fromiter(self.open, np.int64, len(self.open))
        busy: dict[int, int] = {}
        for task in self.tasks.values():
            if task.robot >= 0 and task.done == 0:
                busy[task.errands[0]] = busy.get(task.errands[0], 0) + 1
        by_cell: dict[int, list[Task]] = {}
        for task in self.open.values():
            by_cell.setdefault(task.errands[0], []).append(task)
        out: list[int] = []
        for cell, tasks in by_cell.items():
            room = self.station_cap - busy.get(cell, 0)
            if room >= len(tasks):
                out.extend(t.id for t in tasks)
            elif room > 0:
                tasks.sort(key=lambda t: (self.rank(t), self.length(t), t.id))
                out.extend(t.id for t in tasks[:room])
        return np.array(sorted(out), dtype=np.int64)

    def length(self, task: Task) -> int:
        """The task's estimated moves from its first errand to its last (by ``leg``, 0
        without one), computed when first asked (schedulers ask for open tasks only)."""
        if task.length < 0:
            task.length = sum(self.leg(a, b) for a, b in pairwise(task.errands)) \
                if self.leg is not None else 0
        return task.length

    def waiting(self, task: Task, now: float | None = None) -> float:
        """How long the task has been queued without a robot, in all (until ``now``, default
        the pool's latest time): a task handed back and given to a robot in the same
        scheduling round did not wait; an operator's pause does not count."""
        t = self.now if now is None else now
        return task.waited + (max(0.0, t - task.queued_at) if task.queued_at >= 0 else 0.0)

    def overdue(self, task: Task) -> bool:
        """Whether the task has waited (:meth:`waiting`) :attr:`max_wait` or longer."""
        return self.max_wait is not None and self.waiting(task) >= self.max_wait

    def rank(self, task: Task) -> tuple[int, int, float]:
        """The schedulers' order of open tasks: higher priority first; within a priority the
        overdue ones (:meth:`overdue`) first, the longest waiting first, then the others by
        earlier deadline. So with robots coming free a task waits at most about
        ``max_wait`` plus the time to serve the overdue tasks of its priority before it
        (before that, aging makes a waiting task cheaper for the schedulers)."""
        if self.overdue(task):
            return -task.priority, 0, -self.waiting(task)
        return -task.priority, 1, task.urgency[1]

    def waits(self, now: float) -> list[float]:
        """Assignment waits of the kept tasks (pool time units): how long each waited without
        a robot (:meth:`waiting`, until ``now`` for one still queued). Cancelled tasks are
        left out."""
        return [self.waiting(t, now) for t in self.book.values() if t.state != "cancelled"]

    def _took(self, task: Task, now: float) -> None:
        """The task stops waiting at ``now`` (a robot took it, or it was paused)."""
        if task.queued_at >= 0:
            task.waited += max(0.0, now - task.queued_at)
            task.queued_at = -1

    def assign(self, task_id: int, robot: int, now: float | None = None) -> Task:
        """Give an open task to ``robot`` (at ``now``, default: the pool's latest time)."""
        task = self.open.pop(task_id)
        task.robot = robot
        task.state = "assigned"
        self._released.pop(task_id, None)
        if now is not None:
            self.now = max(self.now, now)
        self._took(task, self.now if now is None else now)
        if robot != task.announced:  # given back to the same robot: no change to tell
            task.assigned_at = self.now if now is None else now
            self._event(task, task.assigned_at)
        return task

    def release(self, task_id: int, now: float | None = None) -> None:
        """Take an assigned task whose first errand is not done back into ``open`` (so a
        scheduler may give it to another robot). Its ``queued`` event is made by the next
        :meth:`settle` unless it goes back to the same robot first."""
        task = self.tasks[task_id]
        if task.robot < 0 or task.done:
            raise ValueError(f"task {task_id} is not assigned or already started")
        task.robot = -1
        task.state = "queued"
        self.open[task_id] = task
        self._released[task_id] = None
        if now is not None:
            self.now = max(self.now, now)
        task.queued_at = self.now if now is None else now

    def settle(self, now: float) -> None:
        """Make the events of released tasks nobody took back (called by every timed change;
        a driver calls it after a scheduling round)."""
        self.now = max(self.now, now)
        if not self._released:
            return
        released, self._released = self._released, {}
        for task_id in released:
            task = self.book.get(task_id)
            if task is not None and task.state == "queued" and task.announced >= 0:
                self._event(task, self.now)

    def errand_done(self, task_id: int, tick: float, robot: int | None = None) -> bool:
        """Its robot reached the task's next errand; True if that finished the task (which
        leaves the pool and reveals the next one). Ignored (False) for a task that left the
        pool unstarted (cancelled, paused) or, with ``robot``, went to another robot."""
        self.settle(tick)
        task = self.tasks.get(task_id)
        if task is None or (robot is not None and task.robot != robot):
            if task_id in self.book:
                return False
            raise KeyError(task_id)
        task.done += 1
        task.errand_at.append(tick)
        if task.done < len(task.errands):
            task.state = "started"
            self._event(task, tick)
            return False
        task.finish_tick = tick
        task.state = "finished"
        del self.tasks[task_id]
        self.finished += 1
        self._event(task, tick)
        self._end(task)
        self.top_up(tick)
        return True

    # ------------------------------------------------------------------ the API's side
    def submit(self, new: Sequence[NewTask], now: float, key: str | None = None
               ) -> tuple[list[int], bool]:
        """Add tasks (one submission); returns their ids and whether they are new. With a
        ``key`` seen before: the same ids if the request is the same, else TaskConflict."""
        request = tuple(new)
        if key is not None and key in self._keys:
            before, ids = self._keys[key]
            if before != request:
                raise TaskConflict(f"idempotency key {key!r} was used for a different request "
                                   f"(tasks {_ids(ids)})")
            return list(ids), False
        if not request:
            raise TaskError("a submission needs at least one task")
        for i, t in enumerate(request):
            if not t.errands:
                raise TaskError(f"task {i} of the submission has no errands")
        self.settle(now)
        ids = []
        batch = self.next_id
        for t in request:
            task = Task(self.next_id, tuple(t.errands), int(now), priority=t.priority,
                        deadline=t.deadline, key=key, submitted=now, batch=batch)
            self.next_id += 1
            self.book[task.id] = task
            ids.append(task.id)
            self._event(task, now)
            self._wait(task)
        if key is not None:
            self._keys[key] = (request, ids)
            while len(self._keys) > self.keep:
                self._keys.popitem(last=False)
        self._rebalance(now)
        return ids, True

    def task(self, task_id: int) -> Task:
        """A kept task; TaskNotFound if there is none."""
        task = self.book.get(task_id)
        if task is None:
            if 0 <= task_id < self.next_id:
                raise TaskNotFound(f"task {task_id} ended long ago and is no longer kept")
            raise TaskNotFound(f"no task {task_id}")
        return task

    def cancel(self, task_id: int, now: float) -> Task:
        """Cancel a task no errand of which is done (cancelling a cancelled one changes
        nothing); TaskConflict if it is started or finished."""
        task = self.task(task_id)
        if task.state == "cancelled":
            return task
        self._check_unstarted(task, "cancelled")
        self.settle(now)
        self._withdraw(task)
        task.state = "cancelled"
        task.cancelled_at = now
        self._event(task, now)
        self._end(task)
        self.top_up(now)
        return task

    def pause(self, task_id: int, now: float) -> Task:
        """Hold a task no errand of which is done: it is not assigned until resumed (taken
        from its robot if it had one). Pausing a paused task changes nothing."""
        task = self.task(task_id)
        if task.state == "paused":
            return task
        self._check_unstarted(task, "paused")
        self.settle(now)
        self._withdraw(task)
        self._took(task, now)
        task.state = "paused"
        self._paused[task_id] = task
        self._event(task, now)
        self.top_up(now)
        return task

    def resume(self, task_id: int, now: float) -> Task:
        """Queue a paused task again (a task that is not paused is left as it is, unless it
        ended: TaskConflict)."""
        task = self.task(task_id)
        if task.state in ("finished", "cancelled"):
            raise TaskConflict(f"task {task_id} is {task.state}: it cannot be resumed")
        if task.state != "paused":
            return task
        self.settle(now)
        del self._paused[task_id]
        task.state = "queued"
        task.queued_at = now
        self._event(task, now)
        self._wait(task)
        self._rebalance(now)
        return task

    def _check_unstarted(self, task: Task, what: str) -> None:
        if task.state in ("finished", "cancelled"):
            raise TaskConflict(f"task {task.id} is {task.state}: it cannot be {what}")
        if task.done:
            raise TaskConflict(f"task {task.id} is started (robot {task.robot} has done "
                               f"{task.done} of its {len(task.errands)} errands): it cannot "
                               f"be {what}")

    def _withdraw(self, task: Task) -> None:
        """Take an unstarted task out of wherever it waits or from its robot."""
        self.tasks.pop(task.id, None)
        self.open.pop(task.id, None)
        self._waiting.pop(task.id, None)
        self._paused.pop(task.id, None)
        task.robot = -1

    def _event(self, task: Task, t: float) -> None:
        self.event_seq += 1
        self.events.append(TaskEvent(self.event_seq, task.id, task.state, task.robot, task.done,
                                     t))
        task.announced = task.robot

    def _end(self, task: Task) -> None:
        self._ended[task.id] = task
        while len(self._ended) > self.keep:
            old, _ = self._ended.popitem(last=False)
            del self.book[old]

    # ------------------------------------------------------------------ rebuilding
    def restore(self, event: TaskEvent, new: NewTask | None = None, key: str | None = None,
                listed: bool = False, batch: int = -1) -> None:
        """Apply one journaled event (a restart rebuilds the book from them, in order);
        ``new`` says what the task is if the book does not know it yet. Events the pool made
        itself already (the task list's first reveal) only set the state again."""
        task = self.book.get(event.task)
        if task is None:
            if new is None:
                raise ValueError(f"event {event.seq} is about task {event.task}, which no "
                                 f"event made")
            task = Task(event.task, new.errands, int(event.t), priority=new.priority,
                        deadline=new.deadline, key=key, submitted=event.t, listed=listed,
                        batch=batch)
            self.book[task.id] = task
            self.next_id = max(self.next_id, task.id + 1)
            self._listed += listed
        if task.state == "finished":
            return
        self._withdraw(task)
        task.state, task.robot, task.done = event.state, event.robot, event.done
        task.announced = event.robot
        del task.errand_at[event.done:]
        task.errand_at.extend([event.t] * (event.done - len(task.errand_at)))
        if event.state == "queued":
            if task.queued_at < 0:
                task.queued_at = event.t
        else:
            self._took(task, event.t)
        match event.state:
            case "queued":
                self._wait(task)
            case "paused":
                self._paused[task.id] = task
            case "assigned" | "started":
                task.assigned_at = event.t if event.state == "assigned" else task.assigned_at
                self.tasks[task.id] = task
            case "finished":
                task.finish_tick = event.t
                self.finished += 1
                self._end(task)
            case "cancelled":
                task.cancelled_at = event.t
                self._end(task)
        if event.seq > self.event_seq:
            self.events.append(event)
            self.event_seq = event.seq
        self.now = max(self.now, event.t)

    def restored(self, now: float) -> None:
        """The journal is applied: rebuild the idempotency keys; tasks assigned but not
        started go back to the queue (the new executor's robots start afresh); started ones
        stay with their robots; reveal what fits."""
        requests: dict[str, tuple[list[NewTask], list[int]]] = {}
        for task in self.book.values():
            if task.key is not None:
                new, ids = requests.setdefault(task.key, ([], []))
                new.append(NewTask(task.errands, task.priority, task.deadline))
                ids.append(task.id)
        for key, (new, ids) in requests.items():
            self._keys[key] = (tuple(new), ids)
        for task in [t for t in self.tasks.values() if t.state == "assigned"]:
            self._withdraw(task)
            task.state = "queued"
            task.queued_at = now
            self._event(task, now)
            self._wait(task)
        self._rebalance(now)

    def events_after(self, seq: int) -> tuple[list[TaskEvent], bool]:
        """The kept events after number ``seq``, and whether none between were dropped."""
        first = self.events[0].seq if self.events else self.event_seq + 1
        start = max(0, seq + 1 - first)
        out = [self.events[i] for i in range(start, len(self.events))]
        return out, seq + 1 >= first or seq >= self.event_seq

    def select(self, states: frozenset[TaskState] | None = None, robot: int | None = None,
               after: int = -1) -> Iterator[Task]:
        """Kept tasks in id order after id ``after``, of ``states`` and on ``robot`` if given."""
        for task_id, task in self.book.items():
            if task_id <= after or (states is not None and task.state not in states) or (
                    robot is not None and task.robot != robot):
                continue
            yield task

    def counts(self) -> dict[TaskState, int]:
        """How many kept tasks are in each state."""
        out: dict[TaskState, int] = dict.fromkeys(TASK_STATES, 0)
        for task in self.book.values():
            out[task.state] += 1
        return out

    def on_robot(self, robot: int) -> Task | None:
        """The task ``robot`` is doing (assigned or started), if any."""
        return next((t for t in self.tasks.values() if t.robot == robot), None)


def wait_percentiles(waits: Sequence[float]) -> dict[str, float]:
    """``p50``, ``p90``, ``p99`` and ``max`` of :meth:`TaskPool.waits` (nearest rank; all 0
    for none)."""
    if not waits:
        return dict.fromkeys(("p50", "p90", "p99", "max"), 0.0)
    ordered = sorted(waits)
    n = len(ordered)
    out = {f"p{q}": float(ordered[max(0, math.ceil(q * n / 100) - 1)]) for q in (50, 90, 99)}
    out["max"] = float(ordered[-1])
    return out


def _ids(ids: Sequence[int]) -> str:
    return ", ".join(map(str, ids[:10])) + (", ..." if len(ids) > 10 else "")


DistanceFrom = Callable[[Sequence[int], Sequence[int]], npt.NDArray[np.signedinteger[Any]]]
"""``f(cells, targets)[i, j]``: moves from ``cells[i]`` to ``targets[j]`` (-1: unreachable), plus
any charge the caller puts on a robot (e.g. one in a delay)."""


class Scheduler(Protocol):
    """Chooses tasks for free robots: ``{robot: task id}`` among ``pool.open``, the most urgent
    first (priority, then overdue, then deadline: :meth:`TaskPool.rank`)."""

    def __call__(self, free: Sequence[tuple[int, int]], pool: TaskPool,
                 distance_from: DistanceFrom) -> dict[int, int]:
        """``free`` lists ``(robot, cell)`` of robots without a task."""
        ...


_CLASS = 1 << 32
"""Cost step between urgency classes (above any distance): a more urgent task goes first."""


def _urgency_rank(pool: TaskPool, ids: npt.NDArray[np.int64]) -> npt.NDArray[np.int64] | None:
    """Each open task's class in :meth:`TaskPool.rank` order (0: first), or None if all are
    alike (the schedulers then weigh distance alone, as without priorities)."""
    keys = [pool.rank(pool.open[int(i)]) for i in ids]
    first = keys[0]
    if all(k == first for k in keys):
        return None
    rank = {k: r for r, k in enumerate(sorted(set(keys)))}
    return np.fromiter((rank[k] for k in keys), np.int64, len(keys))


AGING_FROM = 0.5
"""Aging begins when a task has waited this fraction of ``max_wait`` (a 600 s demo-like shift
in virtual time, 20 robots, 3 seeds, bound 45 s: from 0.5, 263-276 tasks and max wait 41 s
against 264-266 and 348-429 s without a bound; from 0, 259 tasks; a bound without aging, 30 s:
218 tasks, nearly every task then waits for the bound)."""


def _aging(pool: TaskPool, ids: npt.NDArray[np.int64], span: int) -> npt.NDArray[np.int64]:
    """Aging (with :attr:`TaskPool.max_wait`): each task of ``ids`` costs this much less, from
    0 until it has waited :data:`AGING_FROM` of the bound up to ``span`` (the spread of the
    costs) at the bound, so a far or long task comes up gradually before it is overdue
    (instead of every task waiting for the bound)."""
    if pool.max_wait is None:
        return np.zeros(ids.size, dtype=np.int64)
    frac = np.fromiter((pool.waiting(pool.open[int(i)]) / pool.max_wait for i in ids),
                       np.float64, ids.size)
    frac = np.clip((frac - AGING_FROM) / (1.0 - AGING_FROM), 0.0, 1.0)
    return np.rint(frac * span).astype(np.int64)


MATCH_ENTRIES = 8_000_000
"""At most this many robot x task-cell distances in one matching: the robots beyond it (in
the order given) wait for the next call. The matching's work grows with the product (about
30 ns an entry): a first call of brc202d's 6,500 robots for 9,750 tasks on as many cells
(63 million) took 2.1-2.6 s of CPU against LoRR's 1 s for the first call
(``initialPlanTimeLimit``); bounds of 6, 12 and 24 million made it 0.46, 0.69 and 1.16 s
(430, 454, 430 tasks in 600 ticks against 414, one run each). A warehouse's tasks start on a
few hundred stations (3.5 million for warehouse_large's 10,000 robots), and with 1.5 tasks
revealed a robot (the shared LoRR problems') a fleet under 2,300 robots never reaches it."""


def shortest_first(free: Sequence[tuple[int, int]], pool: TaskPool,
                   distance_from: DistanceFrom) -> dict[int, int]:
    """Globally cheapest pairs first (a greedy matching, better than robot order), a pair
    costing the distance to the task's first errand plus the task's own length, so short
    tasks go first (most tasks finished in a fixed time). The more urgent tasks' pairs go
    before the others'. At most :data:`MATCH_ENTRIES` distances a call: the first robots of
    ``free`` up to it (a large fleet's first assignment is spread over the first calls)."""
    ids = pool.offered() if free else np.zeros(0, np.int64)
    if not ids.size:
        return {}
    # tasks that start on the same cell share a column of distances (a warehouse's few
    # hundred stations for 15,000 open tasks)
    cells, column = np.unique(np.fromiter((pool.open[int(i)].errands[0] for i in ids), np.int64,
                                          ids.size), return_inverse=True)
    if len(free) * cells.size > MATCH_ENTRIES:  # the first robots; the others wait a call
        free = free[: max(1, MATCH_ENTRIES // cells.size)]
    dist = distance_from([cell for _, cell in free], cells.tolist())
    column = column.ravel()
    # after distance_from: its tables may serve ``leg``
    extra = np.fromiter((pool.length(pool.open[int(i)]) for i in ids), np.int64, ids.size)
    reach = dist[dist >= 0]
    if reach.size:
        extra -= _aging(pool, ids, int(reach.max() - reach.min() + extra.max() - extra.min()))
    rank = _urgency_rank(pool, ids)
    if rank is not None:
        extra += rank * _CLASS
    # by task cell, then robot (a view of TaskDistances' layout: no copy)
    robots, chosen = greedy_groups(np.asarray(dist, dtype=np.int32).T,
                                   column.astype(np.int64), extra, _UNREACHABLE)
    return {free[r][0]: int(ids[t]) for r, t in zip(robots.tolist(), chosen.tolist(),
                                                    strict=True)}


_UNREACHABLE = np.iinfo(np.int64).max // 4
"""The matching's distance to a task a robot cannot reach (its pairs come after all others)."""


SCHEDULERS: dict[str, Scheduler] = {"shortest": shortest_first}
"""Schedulers by name (``fleetgate lifelong --scheduler``). Two were dropped (issue 28), each
below ``shortest`` on every shared LoRR problem (600 ticks, 3 delay seeds): ``mincost`` (the
greedy matching by the distance to the first errand alone: room 64-82 against 114-122, random
330-355 against 442-460) and ``greedy`` (each free robot in turn takes the task it would
finish soonest, the Start-Kit's default scheduler: maze 1.12, room 0.99 (one seed 0.87),
random 1.05, city 4.4 of the Start-Kit against 1.40, 1.11, 1.12, 6.0)."""
