"""Who works on which task in a lifelong run (pure, no I/O): the scheduling step of a planning
call, the goals it hands the planner, and the errands robots complete while they execute.

A robot has two views of its work, as in Hönig et al.'s persistent execution: the *plan* view
(the task its committed plan drives it to, and how many of that task's errands the committed
plan already reaches) and the *execution* view (errand markers: the robot's count of finished
actions at which it stands on an errand cell). The virtual-time runner
(:mod:`sim_clients.lifelong`) and the gateway's lifelong executor
(:mod:`gateway.execution.lifelong.executor`) share this book, so both schedule and count alike.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable, Iterable, Sequence

import numpy as np
import numpy.typing as npt

from gateway.execution.lifelong.tasks import Scheduler, TaskPool
from gateway.planning.grid import Grid
from gateway.planning.pibt import UNREACHABLE, StateSpace


class TaskDistances:
    """The scheduler's costs: exact moves between cells (one cached table per target cell;
    the graph is undirected, so a table gives the moves from every cell to it and back), plus
    ``charge`` moves for a robot standing on a cell of :attr:`charged` (e.g. one in a delay),
    so tasks go to robots that can go. ``space``: a state space whose tables are the moves over
    the free cells (neither :attr:`~gateway.planning.pibt.StateSpace.exact` nor ``compact``) to
    share them with, e.g. the planner's on a large map, where the robots' goals are the tasks'
    errands."""

    def __init__(self, grid: Grid, charge: int = 0, budget_bytes: int = 1 << 30,
                 space: StateSpace | None = None) -> None:
        if space is not None and (space.exact or space.compact):
            raise ValueError("the scheduler can share only tables over the free cells (moves)")
        self.space = space if space is not None else StateSpace(grid, turning=False,
                                                                budget_bytes=budget_bytes)
        self.charge = charge
        self.charged: set[int] = set()
        """End cells of the robots charged at this planning call."""

    def leg(self, a: int, b: int) -> int:
        """Moves from cell ``a`` to cell ``b``."""
        return int(self.space.distances(a)[self.space.index[b]])

    def __call__(self, cells: Sequence[int], targets: Sequence[int]) -> npt.NDArray[np.int32]:
        """``out[i, j]``: moves from ``cells[i]`` to ``targets[j]`` (-1: unreachable), plus
        the charge (a :data:`~gateway.execution.lifelong.tasks.DistanceFrom`; a transposed view of
        a C-contiguous ``[target, cell]`` array). One table per distinct target, taken in
        blocks that fit the cache (thousands of targets at a call)."""
        space = self.space
        unique, inverse = np.unique(np.asarray(targets, dtype=np.int64), return_inverse=True)
        src = space.index[np.asarray(cells, dtype=np.int64)]
        by_target = np.empty((unique.size, len(cells)), dtype=np.int32)  # rows: fast writes
        block = max(1, space.capacity // 2)
        for i in range(0, unique.size, block):
            part = unique[i : i + block].tolist()
            space.prefetch(part)
            for j, g in enumerate(part, i):
                by_target[j] = np.frombuffer(space.distances(g), dtype=np.int16)[src]
        by_target[by_target >= UNREACHABLE] = -1
        if self.charged:
            rows = [i for i, c in enumerate(cells) if c in self.charged]
            charged = by_target[:, rows]
            charged[charged >= 0] += self.charge
            by_target[:, rows] = charged
        inverse = inverse.ravel()
        if unique.size != inverse.size or (inverse != np.arange(inverse.size)).any():
            by_target = by_target[inverse]
        return by_target.T  # a view: the schedulers read it by target (no 200 MB copy)


class ErrandBook:
    """Each robot's task in the plan view and its errand markers in the execution view."""

    def __init__(self, pool: TaskPool, n_robots: int) -> None:
        self.pool = pool
        self.plan_task = [-1] * n_robots
        """The task the committed plan drives each robot to (-1: none)."""
        self.plan_idx = [0] * n_robots
        """How many of that task's errands the committed plan reaches."""
        self.markers: list[deque[tuple[int, int]]] = [deque() for _ in range(n_robots)]
        """Per robot, in order: (finished-action count at which it stands on an errand, task)."""
        self.on_marker: Callable[[int, int, int], None] | None = None
        """Told ``(robot, count, task)`` of every marker :meth:`register` appends (a driver
        that turns errands into vehicle actions, e.g. VDA 5050's pick and drop)."""
        self.adopt()

    def adopt(self) -> None:
        """Robots go on with the tasks the pool says they do (a pool rebuilt from the
        journal after a restart: the errands done count, the rest is planned anew)."""
        for task in self.pool.tasks.values():
            if 0 <= task.robot < len(self.plan_task):
                self.plan_task[task.robot], self.plan_idx[task.robot] = task.id, task.done

    def release_unstarted(self, now: float, robots: Iterable[int] | None = None) -> None:
        """Tasks whose first errand is not planned yet go back to the pool's open tasks,
        except overdue ones (:meth:`~gateway.execution.lifelong.tasks.TaskPool.overdue`): their
        robot keeps them, so they are not handed from robot to robot while they wait. Only the
        tasks of ``robots`` if given (a bounded share of a large fleet at each call)."""
        pool = self.pool
        pool.now = max(pool.now, now)
        for r in range(len(self.plan_task)) if robots is None else robots:
            task_id = self.plan_task[r]
            if task_id >= 0 and self.plan_idx[r] == 0 and not pool.overdue(pool.tasks[task_id]):
                pool.release(task_id, now)
                self.plan_task[r] = -1

    def forget_gone(self) -> None:
        """Drop plan-view tasks that left the pool or went to another robot (e.g. cancelled)."""
        tasks = self.pool.tasks
        for r, task_id in enumerate(self.plan_task):
            if task_id >= 0 and (task_id not in tasks or tasks[task_id].robot != r):
                self.plan_task[r] = -1

    def schedule(self, end_cells: Sequence[int], scheduler: Scheduler,
                 distances: TaskDistances, now: float) -> list[tuple[int, int]]:
        """Give open tasks to the robots without one (standing at ``end_cells``, where their
        committed plan ends) at ``now``; returns the new ``(robot, task id)`` pairs."""
        free = [(r, end_cells[r]) for r, t in enumerate(self.plan_task) if t < 0]
        self.pool.now = max(self.pool.now, now)  # what is overdue is judged at ``now``
        pairs = list(scheduler(free, self.pool, distances).items())
        for r, task_id in pairs:
            self.pool.assign(task_id, r, now)
            self.plan_task[r], self.plan_idx[r] = task_id, 0
        self.pool.settle(now)  # released tasks nobody took back become events
        return pairs

    def goals(self) -> list[tuple[int, ...]]:
        """Each robot's remaining errand cells in the plan view (empty: no task)."""
        tasks = self.pool.tasks
        return [tasks[t].errands[self.plan_idx[r]:] if t >= 0 else ()
                for r, t in enumerate(self.plan_task)]

    def planned(self, reached: Sequence[Sequence[int]]) -> list[int]:
        """A window was planned that reaches ``reached[r]`` errands of robot r's task: advance
        the plan view. Returns the tasks the window worked on (for :meth:`register`)."""
        tasks_of = list(self.plan_task)
        tasks = self.pool.tasks
        for r, hits in enumerate(reached):
            if self.plan_task[r] < 0:
                continue
            task = tasks.get(self.plan_task[r])
            if task is None or task.robot != r:  # cancelled or paused while it was planned
                self.plan_task[r] = tasks_of[r] = -1
            elif hits:
                self.plan_idx[r] += len(hits)
                if self.plan_idx[r] >= len(task.errands):
                    self.plan_task[r] = -1
        return tasks_of

    def register(self, before: Sequence[int], states: Sequence[Sequence[int]],
                 reached: Sequence[Sequence[int]], tasks_of: Sequence[int]) -> None:
        """Markers of an appended window: robot r had ``before[r]`` actions appended before it,
        ``states[j][r]`` is its planner state at step j (a change is an action), and it stands
        on an errand of task ``tasks_of[r]`` after each step of ``reached[r]``."""
        for r, hits in enumerate(reached):
            if not hits or tasks_of[r] < 0:
                continue
            count, j_prev = 0, 0
            for j in hits:
                for k in range(j_prev + 1, j + 1):
                    if states[k][r] != states[k - 1][r]:
                        count += 1
                j_prev = j
                self.markers[r].append((before[r] + count, tasks_of[r]))
                if self.on_marker is not None:
                    self.on_marker(r, before[r] + count, tasks_of[r])

    def retract(self, appended: Sequence[int], now: float) -> None:
        """The robots' committed actions were taken back to ``appended[r]`` actions
        (:meth:`~gateway.execution.lifelong.live_adg.LiveADG.retract`): drop the markers
        beyond, and the plan view goes back to the first errand not reached any more; tasks
        the robot was to start after it go back to the pool."""
        pool = self.pool
        tasks = pool.tasks
        for r, count in enumerate(appended):
            q = self.markers[r]
            removed = []
            while q and q[-1][0] > count:
                removed.append(q.pop()[1])
            if not removed:
                continue
            first = removed[-1]
            for task_id in {*removed, self.plan_task[r]} - {first, -1}:
                task = tasks.get(task_id)
                if task is not None and task.robot == r and not task.done:
                    pool.release(task_id, now)
            task = tasks.get(first)
            if task is None or task.robot != r:
                self.plan_task[r] = -1
                continue
            self.plan_task[r] = first
            self.plan_idx[r] = task.done + sum(1 for _, t in q if t == first)

    def reach(self, robot: int, done: int) -> list[int]:
        """Robot ``robot`` has finished ``done`` actions: the tasks whose next errand that
        completes, in order (the caller tells the pool)."""
        q = self.markers[robot]
        out = []
        while q and done >= q[0][0]:
            out.append(q.popleft()[1])
        return out
