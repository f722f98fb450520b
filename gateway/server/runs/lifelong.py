"""Lifelong mode inside the gateway: a warehouse shift run by the engine's owner task.

:class:`LifelongRun` owns the shift's sans-I/O
:class:`~gateway.execution.lifelong.executor.LifelongExecutor` (tasks, live ADG, dispatch,
monitor) and routes what it emits: dispatches, the slack trigger and the end of the shift go
through the engine's routing (the same wire protocol as a one-shot run: action ids are
``run.segment.robot.n``, ``n`` counting the robot's actions over the shift, so they never
repeat); a :class:`~gateway.execution.lifelong.executor.PlanRequest` goes to the windowed planner in
its own process (:class:`~gateway.server.runs.planner_process.PlannerProcess`, so it never holds
the event loop's GIL; a thread waits for it in real time, its CPU time is charged under a
virtual clock) while robots keep reporting, and its segment comes back through the owner's
queue as an :class:`~gateway.server.items.OwnerCall` to be appended to the live ADG. Nobody
stops for it. If the planner process dies, one error line says so and the next period plans
again in a new one. The planner process starts while the gateway replays its journal (a
restart), and the gateway is ready once both are done. While the planner is idle it computes
the distance tables of the tasks that come into the pool (its own, and the scheduler's, which
it sends back to the scheduler's cache), so the first planning calls find them ready; a table
is a function of the grid and the cell only, so nothing depends on when one arrives. The
engine ticks the run every monitor period (and when a planning call is due); robot reports
reach the executor through the engine's robot sessions as in a one-shot run.

The live task pool is :attr:`LifelongRun.tasks`: a task API reads it and submits to it from
the owner task.

With a journal the executor is a :class:`~gateway.server.runs.shift_journal.JournaledLifelong`:
its inputs (adopted segments included) are journaled before they are applied, and a restarted
gateway replays them and continues the same shift (:meth:`LifelongRun.resume`,
:mod:`gateway.server.runs.shift_journal`); the task book is journaled too
(:mod:`gateway.server.runs.task_journal`).
"""

from __future__ import annotations

import asyncio
import logging
from array import array
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from functools import partial

from gateway.execution.actions import ActionDurations
from gateway.execution.commands import Command
from gateway.execution.core import Core
from gateway.execution.errors import ExecutionError
from gateway.execution.lifelong.errands import TaskDistances
from gateway.execution.lifelong.executor import (
    LifelongMode,
    PlanRequest,
    Segment,
)
from gateway.execution.lifelong.shift_state import HistoryLog
from gateway.execution.lifelong.tasks import TaskPool, wait_percentiles
from gateway.planning.grid import Grid
from gateway.planning.lorr import random_problem, read_problem, warehouse_problem
from gateway.planning.movingai import read_map
from gateway.runtime.journal import (
    EncodedReport,
    JournalError,
    JournalRecord,
    ShiftHistoryRecord,
    ShiftRecord,
    ShiftSnapshotRecord,
    TaskRecord,
    new_run_id,
)
from gateway.runtime.mapstore import MapNotFound, resolve
from gateway.server.config import GatewayConfig
from gateway.server.items import OwnerCall, SolverDone
from gateway.server.runs.base import RunContext, RunRefused
from gateway.server.runs.planner_process import PlannerDied, PlannerFailed, PlannerProcess, Warm
from gateway.server.runs.shift_journal import JournaledLifelong, compact_shift, resume_shift
from gateway.server.runs.task_journal import TaskJournal, restore_tasks
from gateway.server.views import ShiftView
from protocol import Pose
from protocol.messages import HEADINGS, GatewayStatus

log = logging.getLogger("fleetgate.lifelong")
log_tasks = logging.getLogger("fleetgate.tasks")


@dataclass(frozen=True)
class Shift:
    """What a shift runs on: the map, the robots' start cells (flat ids) and headings (None:
    ``omni``), the task list and how many tasks are kept revealed."""

    name: str
    grid: Grid
    starts: tuple[int, ...]
    headings: tuple[int, ...] | None
    tasks: tuple[tuple[int, ...], ...]
    reveal: int


def shift_from(config: GatewayConfig) -> Shift:
    """The shift ``config.lifelong`` describes (ValueError, one line, if it cannot be read)."""
    s = config.lifelong
    assert s is not None
    if s.problem is not None:
        prob = read_problem(s.problem)
    elif config.shift_map is not None:
        try:
            prob = random_problem(read_map(resolve(config.shift_map, "map")), s.robots, s.seed)
        except (MapNotFound, OSError) as exc:
            raise ValueError(f"lifelong.map: {exc}") from None
    else:
        prob = warehouse_problem(s.robots, s.seed, s.warehouse, p_delay=0.0)
    n = prob.team_size
    headings = (config.start_heading,) * n if config.motion == "turning" else None
    reveal = max(1, int((s.reveal or prob.num_tasks_reveal) * n))
    return Shift(prob.name or "warehouse", prob.grid, prob.starts, headings,
                 prob.tasks if s.task_list else (), reveal)


class LifelongRun:
    """A shift inside the gateway: its executor, its planner off the loop, its routing."""

    def __init__(self, engine: RunContext, shift: Shift) -> None:
        cfg = engine.config
        s = cfg.lifelong
        assert s is not None
        self._engine = engine
        self.shift = shift
        grid = shift.grid
        distances = TaskDistances(grid)
        try:
            pool = TaskPool(shift.tasks, shift.reveal, leg=distances.leg,
                            max_wait=s.max_wait_ms)
        except ValueError as exc:
            raise ValueError(f"lifelong mode: {exc}") from None
        self.executor = JournaledLifelong(
            grid, shift.starts, shift.headings, pool, scheduler=s.scheduler,
            distances=distances, period_ms=s.period_ms, window=s.window,
            durations=ActionDurations.uniform(cfg.action_ms), lookahead=cfg.dispatch_lookahead,
            threshold_ms=s.threshold_ms, record=engine.feed.record)
        engine.metrics.waits = self.wait_percentiles_s
        engine.metrics.task_counts = lambda: {str(k): n for k, n in self.tasks.counts().items()}
        self._counted = 0  # the last task event counted in the metrics
        engine.before_commit.append(self._count_tasks)
        self.turning = shift.headings is not None
        self.planner = PlannerProcess(grid, len(shift.starts), self.turning, s.seed)
        try:  # waited for by :meth:`planner_ready`: a restart replays its journal meanwhile
            self.planner.start(wait=False)
        except PlannerDied as exc:
            raise ValueError(f"lifelong mode: {exc}") from None
        self.planner_ms: list[float] = []
        """Wall (real clock) or charged (virtual clock) ms of each planner call."""
        self._solving: asyncio.Task[None] | None = None
        self._warm = _WarmQueue(distances)
        self._warming: asyncio.Task[None] | None = None
        engine.before_commit.append(self._warm_tasks)
        self.started: ShiftRecord | None = None
        """The shift's start (its run id, wall time and speed of time 0), once started."""
        self.after_adopt: Callable[[], None] | None = None
        """Called after each adopted segment is routed (the journal compacts here)."""

    async def planner_ready(self) -> None:
        """Wait, off the event loop, until the planner process has built its planner
        (ValueError, one line, if it cannot): the shift's first call needs it."""
        try:
            await self._engine.clock.wait_for(self.planner.start)
        except PlannerDied as exc:
            raise ValueError(f"lifelong mode: {exc}") from None

    # ------------------------------------------------------------------ state
    @property
    def tasks(self) -> TaskPool:
        """The live task pool."""
        return self.executor.pool

    def wait_percentiles_s(self) -> dict[str, float]:
        """The tasks' assignment waits so far (s): ``p50``, ``p90``, ``p99``, ``max``."""
        waits = self.tasks.waits(self.now_ms())
        return {k: v / 1000.0 for k, v in wait_percentiles(waits).items()}

    @property
    def robots(self) -> int:
        """The fleet's size."""
        return self.executor.n

    def now_ms(self) -> float:
        """The shift's clock: plan ms since the shift started, 0 before it (the task API's
        one clock: a task submitted before the start is submitted at 0)."""
        if self.executor.mode is LifelongMode.NEW:
            return 0.0
        return self._engine.now_ms()

    def counted_until(self, seq: int) -> None:
        """Task events up to ``seq`` are not counted in the metrics (a restarted gateway's
        replayed ones were counted by the process before it)."""
        self._counted = seq

    @property
    def period_ms(self) -> float:
        """Plan time between planning calls."""
        s = self._engine.config.lifelong
        assert s is not None
        return s.period_ms

    @property
    def core(self) -> Core[object]:
        """The shift's executor: robot reports go there."""
        return self.executor

    @property
    def plan_id(self) -> int | None:
        """A shift names no plan in a welcome (its segments are in the action ids)."""
        return None

    @property
    def planner_busy(self) -> bool:
        """A segment asked of the planner and not adopted yet."""
        return self.executor.outstanding is not None

    @property
    def loads_plans(self) -> bool:
        """A shift's map and tasks come from the configuration: nothing is loaded."""
        return False

    @property
    def active(self) -> bool:
        """A shift's speed changes are always journaled."""
        return True

    @property
    def shift_view(self) -> ShiftView:
        """The shift as a snapshot shows it."""
        return ShiftView(self.shift.name, self.executor, self.period_ms)

    @property
    def ticking(self) -> bool:
        """Whether the engine must tick the run (started and not done)."""
        return self.executor.mode in (LifelongMode.RUNNING, LifelongMode.STOPPING)

    @property
    def status(self) -> GatewayStatus:
        """The gateway's status while in lifelong mode."""
        mode = self.executor.mode
        if mode is LifelongMode.NEW:
            return "loaded"
        if mode is LifelongMode.DONE:
            return "done"
        return "paused" if self.executor.paused else "running"

    def pose(self, robot: int) -> Pose | None:
        """Where a robot stands now (its welcome's start), None for an unknown robot."""
        if not 0 <= robot < self.executor.n:
            return None
        cell, heading = self.executor.pose(robot)
        return Pose(cell=self.shift.grid.cell(cell),
                    heading=None if heading is None else HEADINGS[heading])

    # ------------------------------------------------------------------ lifecycle
    def start(self) -> None:
        """Start the shift at plan time 0 (action ids get a fresh run id); RunRefused unless
        it is loaded (not started yet)."""
        e = self._engine
        if self.status != "loaded":
            raise RunRefused(f"cannot start while {e.status}")
        for gs in e.robots.values():
            gs.new_run()
        e.summary = None
        e.finished_event.clear()
        e.paused = False
        e.feed.new_run()
        e.runs += 1
        e.run_id = new_run_id()
        e.clock.reset()
        self.started = ShiftRecord(run_id=e.run_id, wall_start_s=e.clock.wall_s(),
                                   speed=e.clock.speed)
        if self.executor.sink is not None:
            self.executor.sink(self.started)
        self.executor.start(0.0)
        e.status_changed()
        self.route()
        log.info("lifelong shift started", extra={
            "run": e.run_id, "robots": self.robots, "map": self.shift.name})

    def autostart(self) -> None:
        """Start once the whole fleet is online."""
        if self._engine.all_online(self.robots):
            self.start()

    def replan_now(self) -> str:
        """The operator's "plan now": a planning call at once (not while paused)."""
        e = self._engine
        if e.paused:
            raise RunRefused(f"cannot replan while {e.status}")
        try:
            self.executor.plan_now(e.now_ms())
        except ExecutionError as exc:
            raise RunRefused(str(exc)) from None
        self.route()
        return "planning a window now"

    def policy_changed(self, *, replace: bool) -> None:
        """A shift has no replanning policy; a new threshold is its slack trigger's."""
        if not replace:
            self.executor.set_threshold(self._engine.threshold_ms)

    def solver_done(self, item: SolverDone) -> None:
        """A shift's planner answers through the owner queue (:meth:`plan_window`), never as
        a solver task."""

    def monitor_tick(self, now_ms: float) -> None:
        """The engine's tick: :meth:`tick`, and the fleet slack to the operators."""
        self.tick(now_ms)
        self._engine.feed.slack(now_ms, self.executor.fleet_slack_ms)

    def stop(self) -> str:
        """End the shift: nothing new is dispatched; done when every robot is idle
        (:class:`RunRefused` unless it runs)."""
        try:
            self.executor.stop(self._engine.now_ms())
        except ExecutionError as exc:
            raise RunRefused(str(exc)) from None
        self.route()
        return "stopping the shift"

    def set_paused(self, paused: bool) -> None:
        """Dispatch nothing new while paused (robots are paused by their sessions)."""
        now = self._engine.now_ms()
        (self.executor.pause if paused else self.executor.resume)(now)
        self.route()

    def tick(self, now_ms: float) -> None:
        """A monitor tick: planning calls and the slack check."""
        self.executor.tick(now_ms)
        self.route()

    def cancel(self) -> None:
        """Cancel a running planner call and end the planner process (the gateway is
        closing)."""
        for task in (self._solving, self._warming):
            if task is not None:
                task.cancel()
        self.planner.close()

    # ------------------------------------------------------------------ journal
    def resume(self) -> bool:
        """Journal the shift from now on (its task book, and its executor's inputs), after
        rebuilding it from the engine's journal (True if there was something to rebuild): a
        journaled shift is replayed and goes on (:func:`~.shift_journal.resume_shift`); task
        records alone (tasks submitted before a shift started, or a journal of a gateway that
        journaled only its tasks) rebuild the book. A journaled one-shot run is a
        :class:`JournalError` (``--fresh`` abandons it). Without a journal: False."""
        e = self._engine
        journal, pool = e.journal, self.tasks
        if journal is None:
            return False
        records: list[JournalRecord] = list(journal.records())
        if records and not isinstance(records[0], TaskRecord | ShiftRecord
                                      | ShiftSnapshotRecord | ShiftHistoryRecord):
            raise JournalError(f"the journal {journal.path} holds a one-shot run and the "
                               f"gateway is in lifelong mode: start with --fresh to abandon it")
        last = 0
        history = HistoryLog()
        if any(isinstance(rec, ShiftRecord | ShiftSnapshotRecord) for rec in records):
            history = HistoryLog(resume_shift(e, self, records).history)
            last = pool.event_seq
        elif records:
            last = restore_tasks(pool, records, pool.now)
            self.executor.book.adopt()  # robots go on with their started tasks
            log_tasks.info("task book rebuilt from the journal", extra={
                "records": len(records), "tasks": len(pool.book), "finished": pool.finished})
        tasks = TaskJournal(pool, journal, last)
        self.counted_until(last)
        e.before_commit.append(tasks.flush)

        def sink(rec: JournalRecord | EncodedReport) -> None:
            tasks.flush()  # the task changes before the input first: the replay's order
            journal.append(rec)

        self.executor.sink = sink
        s = e.config.lifelong
        assert s is not None
        self.after_adopt = partial(compact_shift, e, self, history, s.snapshot_segments)
        return bool(records)

    def _count_tasks(self) -> None:
        """Before each commit: the tasks finished since the last one into the metrics (their
        count, each one's time from submission to finish and its time without a robot)."""
        pool = self.tasks
        if pool.event_seq == self._counted:
            return
        events, _ = pool.events_after(self._counted)
        self._counted = pool.event_seq
        metrics = self._engine.metrics
        for event in events:
            if event.state == "finished":
                metrics.tasks_finished.inc()
                task = pool.book.get(event.task)
                if task is not None:
                    metrics.task_completion.observe(max(0.0, event.t - task.submitted) / 1000.0)
                    metrics.task_wait.observe(task.waited / 1000.0)

    # ------------------------------------------------------------------ warming
    def _warm_tasks(self) -> None:
        """Before each commit: have the planner process compute the distance tables of tasks
        new in the pool (its own, and the scheduler's, sent back) while it is idle, so that
        neither the first planning calls nor the event loop build them. A table not there
        in time is computed where it is needed, as before, and a table is a function of the
        grid and the cell only: nothing planned depends on when one arrives."""
        if self._warm.add(self.tasks) and self._warming is None and not self.planner.closed:
            self._warming = asyncio.get_running_loop().create_task(self._warm_loop(),
                                                                   name="lifelong-warm")

    async def _warm_loop(self) -> None:
        try:
            while (req := self._warm.take()) is not None:
                try:
                    tables = await asyncio.to_thread(self.planner.warm, req)
                except PlannerDied as exc:
                    self._planner_died(exc, None)
                    return
                except PlannerFailed as exc:
                    log.error("lifelong planner failed", extra={"call": None,
                                                                "error": str(exc)})
                    return
                self._warm.done(tables)
        finally:
            self._warming = None

    # ------------------------------------------------------------------ routing
    def route(self) -> None:
        """Carry out what the executor emitted: planner calls here, the rest by the engine."""
        rest: list[Command] = []
        for c in self.executor.drain():
            if isinstance(c, PlanRequest):
                self.plan_window(c)
            else:
                rest.append(c)
        if rest:
            self._engine.route(rest)

    def plan_window(self, req: PlanRequest) -> None:
        """Have the planner process answer ``req`` off the loop; its segment comes back
        through the owner queue."""
        e = self._engine

        async def run() -> None:
            segment: Segment | None = None
            try:
                segment, charged = await e.clock.run_measured(partial(self.planner.call, req))
                self.planner_ms.append(charged)
                e.metrics.planner_call.labels("window").observe(charged / 1000.0)
            except PlannerDied as exc:
                self._planner_died(exc, req.call)
            except Exception as exc:  # a planner bug: one line, the next period plans again
                log.error("lifelong planner failed", extra={"call": req.call,
                                                            "error": repr(exc)[:300]})
            e.queue.put_nowait(OwnerCall(partial(self._answered, req, segment)))

        self._solving = asyncio.get_running_loop().create_task(run(), name="lifelong-plan")

    def _planner_died(self, exc: PlannerDied, call: int | None) -> None:
        """One error line (none while the gateway closes); the next call starts a new one."""
        if not self.planner.closed:
            log.error("lifelong planner process died", extra={"call": call,
                                                              "error": str(exc)})

    def _answered(self, req: PlanRequest, segment: Segment | None) -> None:
        """The planner answered ``req`` (None: it failed); runs in the owner task."""
        self._solving = None
        ex = self.executor
        if ex.outstanding is not req:
            return
        now = self._engine.now_ms()
        if segment is not None:
            try:
                ex.adopt(segment, now)
            except ExecutionError as exc:
                log.error("lifelong segment refused", extra={"call": req.call,
                                                             "error": str(exc)})
                segment = None
        if segment is None:
            ex.plan_failed(req.call, now)
        self.route()
        if segment is not None and self.after_adopt is not None:
            self.after_adopt()


class _WarmQueue:
    """The cells whose tables the planner process is to compute, in small requests: the
    scheduler's first (first errands and the starts of the legs of
    :meth:`~gateway.execution.lifelong.tasks.TaskPool.length`: they are cheap, and the first
    planning call on the event loop needs them all), then the planner's (every errand); first
    errands first (every task's, then the later ones)."""

    CHUNK = 64
    """Cells per request (a planner call waits for one: ~0.1 s)."""

    def __init__(self, distances: TaskDistances) -> None:
        self._distances = distances
        self._next_id = 0  # tasks before this id were looked at
        self._goals: deque[int] = deque()  # planner tables to ask for, in order
        self._tables: deque[int] = deque()  # scheduler tables to ask for, in order
        self._queued: tuple[set[int], set[int]] = (set(), set())  # ever queued (cells: bounded)

    def add(self, pool: TaskPool) -> bool:
        """Queue the tables of the tasks submitted or revealed since the last call; True if
        anything is queued."""
        if pool.next_id > self._next_id:
            new = [t.errands for i in range(self._next_id, pool.next_id)
                   if (t := pool.book.get(i)) is not None]
            self._next_id = pool.next_id
            goals, tables = self._queued
            for cells, queue, seen in (([e[0] for e in new], self._goals, goals),
                                       ([e[0] for e in new], self._tables, tables),
                                       ([c for e in new for c in e[1:]], self._goals, goals),
                                       ([c for e in new for c in e[1:-1]], self._tables,
                                        tables)):
                for c in cells:
                    if c not in seen:
                        seen.add(c)
                        queue.append(c)
        return bool(self._goals or self._tables)

    def take(self) -> Warm | None:
        """The next request (None: nothing left to ask for)."""
        tables = _pop(self._tables, self.CHUNK, self._distances.space.cached)
        goals = _pop(self._goals, self.CHUNK // 2) if not tables else []  # 4 states a cell
        return Warm(tuple(goals), tuple(tables)) if goals or tables else None

    def done(self, tables: dict[int, array[int]]) -> None:
        """A request's scheduler tables arrived: into the scheduler's cache."""
        self._distances.space.offer(tables)


def _pop(queue: deque[int], n: int, skip: Callable[[int], bool] | None = None) -> list[int]:
    """Take up to ``n`` cells from the front of ``queue``, leaving out those ``skip`` says."""
    out: list[int] = []
    while queue and len(out) < n:
        cell = queue.popleft()
        if skip is None or not skip(cell):
            out.append(cell)
    return out
