"""Lifelong tasks: a pool of revealed tasks and pluggable schedulers (pure, no I/O).

A task is an ordered list of errand cells (flat ids); a robot completes an errand by arriving
at its cell, and the task when its last errand is done. The pool keeps ``reveal`` tasks
revealed and unfinished (LoRR's ``numTasksReveal`` x team size): each finished task reveals the
next one of the task list, which is cycled when it runs out (task ids keep growing).
"""

from __future__ import annotations

import heapq
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from itertools import pairwise
from typing import Protocol

import numpy as np
import numpy.typing as npt


@dataclass
class Task:
    """A revealed task: its errands, who does it (-1: nobody yet) and how many are done."""

    id: int
    errands: tuple[int, ...]
    release_tick: int
    robot: int = -1
    done: int = 0
    finish_tick: int = -1
    length: int = -1  # estimated moves from its first errand to its last (-1: not yet known)


@dataclass
class TaskPool:
    """Revealed tasks of a task list; ``open`` are the revealed, unassigned ones (by id)."""

    task_list: Sequence[tuple[int, ...]]
    reveal: int
    leg: Callable[[int, int], int] | None = None  # estimated moves between two cells
    tasks: dict[int, Task] = field(default_factory=dict)
    open: dict[int, Task] = field(default_factory=dict)
    finished: int = 0
    next_id: int = 0

    def __post_init__(self) -> None:
        if not self.task_list or any(not t for t in self.task_list):
            raise ValueError("a task pool needs tasks with at least one errand each")
        if self.reveal <= 0:
            raise ValueError("a task pool must reveal at least one task")
        self.top_up(0)

    def top_up(self, tick: int) -> None:
        """Reveal tasks until ``reveal`` are revealed and unfinished."""
        while len(self.tasks) < self.reveal:
            errands = tuple(self.task_list[self.next_id % len(self.task_list)])
            task = Task(self.next_id, errands, tick)
            self.tasks[task.id] = task
            self.open[task.id] = task
            self.next_id += 1

    def length(self, task: Task) -> int:
        """The task's estimated moves from its first errand to its last (by ``leg``, 0
        without one), computed when first asked (schedulers ask for open tasks only)."""
        if task.length < 0:
            task.length = sum(self.leg(a, b) for a, b in pairwise(task.errands)) \
                if self.leg is not None else 0
        return task.length

    def assign(self, task_id: int, robot: int) -> Task:
        """Give an open task to ``robot``."""
        task = self.open.pop(task_id)
        task.robot = robot
        return task

    def release(self, task_id: int) -> None:
        """Take an assigned task whose first errand is not done back into ``open`` (so a
        scheduler may give it to another robot)."""
        task = self.tasks[task_id]
        if task.robot < 0 or task.done:
            raise ValueError(f"task {task_id} is not assigned or already started")
        task.robot = -1
        self.open[task_id] = task

    def errand_done(self, task_id: int, tick: int) -> bool:
        """Its robot reached the task's next errand; True if that finished the task (which
        leaves the pool and reveals the next one)."""
        task = self.tasks[task_id]
        task.done += 1
        if task.done < len(task.errands):
            return False
        task.finish_tick = tick
        del self.tasks[task_id]
        self.finished += 1
        self.top_up(tick)
        return True


DistanceFrom = Callable[[Sequence[int], Sequence[int]], npt.NDArray[np.int64]]
"""``f(cells, targets)[i, j]``: moves from ``cells[i]`` to ``targets[j]`` (-1: unreachable), plus
any charge the caller puts on a robot (e.g. one in a delay)."""


class Scheduler(Protocol):
    """Chooses tasks for free robots: ``{robot: task id}`` among ``pool.open``."""

    def __call__(self, free: Sequence[tuple[int, int]], pool: TaskPool,
                 distance_from: DistanceFrom) -> dict[int, int]:
        """``free`` lists ``(robot, cell)`` of robots without a task."""
        ...


def greedy_nearest(free: Sequence[tuple[int, int]], pool: TaskPool,
                   distance_from: DistanceFrom) -> dict[int, int]:
    """Each free robot in turn takes the open task whose first errand is nearest to it."""
    if not free or not pool.open:
        return {}
    ids = np.fromiter(pool.open, np.int64, len(pool.open))
    first = [pool.open[int(i)].errands[0] for i in ids]
    cost = distance_from([cell for _, cell in free], first).astype(np.int64)
    cost[cost < 0] = np.iinfo(np.int32).max
    out: dict[int, int] = {}
    taken = np.zeros(ids.size, dtype=bool)
    for row, (robot, _) in enumerate(free):
        if taken.all():
            break
        c = np.where(taken, np.iinfo(np.int64).max, cost[row])
        j = int(np.argmin(c))
        taken[j] = True
        out[robot] = int(ids[j])
    return out


def min_cost(free: Sequence[tuple[int, int]], pool: TaskPool,
             distance_from: DistanceFrom) -> dict[int, int]:
    """Globally cheapest pairs first: repeatedly assign the (robot, task) pair with the
    smallest distance to the first errand (a greedy matching, better than robot order)."""
    return _matching(free, pool, distance_from, with_length=False)


def shortest_first(free: Sequence[tuple[int, int]], pool: TaskPool,
                   distance_from: DistanceFrom) -> dict[int, int]:
    """:func:`min_cost` on the whole task: distance to the first errand plus the task's own
    length, so short tasks go first (most tasks finished in a fixed time)."""
    return _matching(free, pool, distance_from, with_length=True)


def _matching(free: Sequence[tuple[int, int]], pool: TaskPool, distance_from: DistanceFrom,
              with_length: bool) -> dict[int, int]:
    if not free or not pool.open:
        return {}
    ids = np.fromiter(pool.open, np.int64, len(pool.open))
    first = [pool.open[int(i)].errands[0] for i in ids]
    big = np.iinfo(np.int64).max // 4
    cost = distance_from([cell for _, cell in free], first).astype(np.int64)
    unreachable = cost < 0
    if with_length:  # after distance_from: its tables may serve ``leg``
        cost += np.fromiter((pool.length(pool.open[int(i)]) for i in ids), np.int64, ids.size)
    cost[unreachable] = big
    return _greedy_pairs(cost, free, ids)


def _greedy_pairs(cost: npt.NDArray[np.int64], free: Sequence[tuple[int, int]],
                  ids: npt.NDArray[np.int64]) -> dict[int, int]:
    """The greedy matching of ``cost[robot row, task column]``: pairs in increasing cost
    (ties in row-major order), each robot and task once. Lazily, as a heap of each row's
    cheapest task not taken yet: the same pairs as sorting all of them, without visiting
    every pair in Python (hundreds of robots x tasks at each planning call)."""
    n_rows, n_cols = cost.shape
    order = np.argsort(cost, axis=1, kind="stable")
    taken = np.zeros(n_cols, dtype=bool)
    ptr = [0] * n_rows
    heap = [(int(cost[r, order[r, 0]]), r * n_cols + int(order[r, 0])) for r in range(n_rows)]
    heapq.heapify(heap)
    out: dict[int, int] = {}
    want = min(n_rows, n_cols)
    while heap and len(out) < want:
        _, f = heapq.heappop(heap)
        r, t = divmod(f, n_cols)
        if taken[t]:  # the row's next task not taken yet goes back on the heap
            row, p = order[r], ptr[r] + 1
            while p < n_cols and taken[row[p]]:
                p += 1
            ptr[r] = p
            if p < n_cols:
                t = int(row[p])
                heapq.heappush(heap, (int(cost[r, t]), r * n_cols + t))
            continue
        taken[t] = True
        out[free[r][0]] = int(ids[t])
    return out


SCHEDULERS: dict[str, Scheduler] = {"greedy": greedy_nearest, "mincost": min_cost,
                                     "shortest": shortest_first}
"""Schedulers by name (``fleetgate lifelong --scheduler``)."""
