"""The owner task: the only code that touches the :class:`Executor` (single writer, no locks).

Connection handlers only validate messages and put them on :attr:`Engine.queue`; the owner
task (:meth:`Engine.run`) takes one item at a time and routes it: a robot's message to that
robot's protocol session (:class:`~protocol.gateway_session.GatewaySession`: the handshake,
acknowledgements, duplicates, what a reconnect catches up and resends), whose effects go to the
robot's connection, the sender (refusals) or the executor (reports, applied with the clock's
time); the executor's commands back to the sessions (dispatch, cancel), to the planner and to
the operator feed; operator commands to :class:`~gateway.server.operator_commands.OperatorCommands`
(which checks them and drives the run's lifecycle: load, start, pause, settings). It also ticks
the executor every ``MONITOR_PERIOD_MS`` while running. The planner runs off-loop in
:class:`~gateway.server.runs.solver_tasks.SolverTasks` while events keep queueing; its result comes
back as a queue item.

The journal (:mod:`gateway.runtime.journal`, optional): the executor is a
:class:`~gateway.server.runs.resume.JournaledExecutor` that journals each of its inputs before
applying it; the run's start, intruder reports and speed changes are journaled too, and the
engine commits the journal (then flushes the trace) every time the owner task is about to
yield to the event loop, so no message it queued leaves the process before its cause is
durable. On start with a journaled run, :meth:`Engine.resume` replays it and carries on;
reconnecting robots are re-synchronised by their ``hello``.

Elsewhere: what operators and the trace file are told (:mod:`gateway.server.operator_feed`),
what a snapshot shows (:mod:`gateway.server.views`, from a read model), the process's garbage
collector (:mod:`gateway.server.gc_tuning`, hooked by the :class:`~gateway.server.gateway.Gateway`).
"""

from __future__ import annotations

import asyncio
import logging
import math
import time
from collections import deque
from collections.abc import Awaitable, Callable, Sequence
from functools import partial
from typing import Any, TypeVar, cast

from gateway.execution.commands import (
    Cancel,
    Command,
    Completed,
    Dispatch,
    PlanAdopted,
    Rescheduled,
    SolveRequest,
    Trigger,
)
from gateway.execution.core import MONITOR_PERIOD_MS, Core
from gateway.execution.errors import ExecutionError
from gateway.execution.trace_records import summary_record
from gateway.planning.solver import Place
from gateway.runtime.journal import IntruderRecord, Journal, ReportRecord, RunRecord
from gateway.runtime.trace import trace_line
from gateway.server.clock import Clock, RealClock
from gateway.server.config import GatewayConfig
from gateway.server.items import (
    Connected,
    Disconnected,
    Inbound,
    InternalCommand,
    Item,
    OwnerCall,
    RobotReports,
    SolverDone,
)
from gateway.server.metrics import Metrics
from gateway.server.operator_commands import OperatorCommands
from gateway.server.operator_feed import OperatorFeed
from gateway.server.planner import Problem
from gateway.server.runs.base import Run
from gateway.server.runs.lifelong import LifelongRun
from gateway.server.runs.oneshot import OneShotRun
from gateway.server.runs.resume import JournaledExecutor
from gateway.server.runs.solver_tasks import SolverTasks
from gateway.server.views import FleetView, snapshot_fields
from gateway.server.wire.session import Session
from protocol import (
    Ack,
    Action,
    ActionRefused,
    Blocked,
    Cancelled,
    CloseCode,
    ErrorCode,
    Finished,
    Hello,
    IntruderReport,
    SetSpeed,
    Snapshot,
    Started,
    State,
    Unblocked,
    action_id,
)
from protocol.gateway_session import (
    GatewaySession,
    Refuse,
    Report,
    ReportKind,
    ToRobot,
    hello_refusal,
)
from protocol.messages import HEADINGS, GatewayStatus, PolicyName, Pose

log = logging.getLogger("fleetgate.engine")


# ------------------------------------------------------------------------------ the engine
_T = TypeVar("_T")

GROUP_COMMIT_ITEMS = 64
"""Queue items handled at most between two commits. What is queued together is handled, then
committed once before the owner task yields (a group commit: 50 WMS clients' submissions cost
one synced commit, not 50, and none is answered before it); at most this many, so that the
task events of as many batches of ``MAX_BATCH`` tasks are still in the task pool's window
(``KEEP``) when they are journaled."""


def _tick_marker() -> None:
    """What a tick item calls if it comes after ticking stopped: nothing (the owner task
    recognises the armed tick's item itself)."""


def _pose(cell: tuple[int, int], heading: int | None) -> dict[str, Any]:
    """A pose as the plain JSON values an action carries (:func:`protocol.encode_action`)."""
    return {"cell": [int(cell[0]), int(cell[1])],
            "heading": None if heading is None else HEADINGS[heading]}


class Engine:
    """Executor owner: routes queue items, robot sessions' effects and executor commands;
    ticks the monitor. Operator commands: :attr:`operator`; planner tasks: :attr:`solvers`."""

    def __init__(self, config: GatewayConfig, clock: Clock, metrics: Metrics) -> None:
        self.config = config
        self.clock = clock
        self.metrics = metrics
        self.queue: asyncio.Queue[Item] = asyncio.Queue()
        self.problem: Problem | None = None
        self.executor: JournaledExecutor | None = None
        self.current_run: Run = OneShotRun(self)
        """The run the engine routes to: a one-shot run (:attr:`problem` and :attr:`executor`
        are its plan and executor), or a lifelong shift the gateway puts here."""
        self.journal: Journal | None = None
        """Where the runs are journaled (None: they are not, and do not survive a restart)."""
        self.run_record: RunRecord | None = None
        """The journaled run's record (its snapshots carry it)."""
        self.run_id = ""
        """The current run's id, the first part of its action ids."""
        self.runs = 0
        """Runs started (or resumed) by this process (ids of runs without a journal)."""
        self.replaying = False
        """True while a run replays its journal (nothing is solved or announced)."""
        self.replayed_trace: list[str] = []
        """The trace records a replay rebuilt."""
        self.planning = False
        self.paused = False
        self.robots: dict[int, GatewaySession] = {}
        self._online: set[int] = set()  # robots with a live session (O(1) autostart check)
        self.feed = OperatorFeed(config.slack_series_len, config.trace)
        self.worlds: set[Session] = set()
        self.policy_name: PolicyName = config.policy
        self.policy_seed = config.policy_seed
        self.threshold_ms = config.threshold_ms
        self.block_history: list[float] = list(config.block_history_ms)
        """How long the blocks of the earlier runs lasted: the next run starts from it."""
        self.latencies_ms: list[float] = []
        self.summary: tuple[float, float] | None = None
        self.finished_event = asyncio.Event()
        self.solvers = SolverTasks(config, clock, self.queue)
        self.operator = OperatorCommands(self)
        self._unlocked_at: float | None = None  # perf_counter of the finish being applied
        self.status_listeners: list[Callable[[GatewayStatus], None]] = []
        self.before_tick: list[Callable[[float], None]] = []
        """Called with the tick's time once the instant is quiet, just before each monitor
        tick (a simulated world in the same process steps its intruder here, in the order of
        the discrete-event driver: robot events, then the world, then the tick)."""
        self.before_start: list[Callable[[], None]] = []
        """Called when a run's objects exist, just before its time 0 (the process driver
        tunes the garbage collector here; what they take is not charged to the run)."""
        self.before_commit: list[Callable[[], None]] = []
        """Called before each commit (the task journal appends the task events here)."""
        self.after_commit: list[Callable[[], None]] = []
        """Called after each commit (the workers' channels write the owner's commands here,
        in this turn rather than the next: what caused them is durable)."""
        self.holding: list[Callable[[bool], None]] = []
        """Called with True before the owner task's batch wait and with False after it: a
        source of items may hold them meanwhile, if it queues them within a loop turn of the
        release (the workers' channels: their frames are then read once a batch, and the owner
        process is not woken for each)."""
        self._tick_failing = False  # the last monitor tick raised (logged once per streak)
        self._flushing: set[int] = set()  # robots whose session's effects are being carried out
        self._routing = False  # a batch of executor commands is being routed
        self._routed_later: deque[Command] = deque()  # commands given meanwhile
        self.meter_cpu = False
        """Measure :attr:`cpu_s` (set before :meth:`run` starts; a benchmark does: it costs
        two reads of the thread's CPU clock per wake-up of the owner task)."""
        self.cpu_s = 0.0
        """With :attr:`meter_cpu`: CPU time of the owner task so far (its own work: items,
        ticks, commits; not the connections' reading, validating and writing, which run in
        tasks of their own)."""
        self._resumed = 0.0  # thread CPU time when the owner task last woke up
        self._handled = 0  # items handled (the queue depth gauge samples every 64th)
        self._uncommitted = 0  # items handled since the last commit
        self._tick_item: OwnerCall | None = None  # the next tick's queue item, once armed
        self._tick_timer: asyncio.TimerHandle | None = None  # the loop timer that queues it
        self._tick_ms = 0.0  # the plan time of the next tick
        self._batch_s = config.batch_ms / 1000.0 if isinstance(clock, RealClock) else 0.0
        """The shortest loop time between two batches (``batch_ms``; 0 in virtual time)."""
        self._batch_at = -self._batch_s  # loop time at which the last batch began

    # -------------------------------------------------------------------------- status
    @property
    def lifelong(self) -> LifelongRun | None:
        """For callers outside the engine (the task API, simulators, tests): the run if it is
        a shift, else None. The engine itself never asks which run it has."""
        run = self.current_run
        return run if isinstance(run, LifelongRun) else None

    def _core(self) -> Core[object] | None:
        """What robot reports go to."""
        return self.current_run.core

    @property
    def status(self) -> GatewayStatus:
        """What the gateway is doing."""
        return self.current_run.status

    def now_ms(self) -> float:
        """The present for the executor (never before its last input)."""
        now = self.clock.now_ms()
        core = self._core()
        return max(now, core.now_ms) if core is not None else now

    def connected_robots(self) -> int:
        """How many robots are connected (said hello on a live connection)."""
        return len(self._online)

    def all_online(self, n: int) -> bool:
        """Whether robots 0..n-1 are all connected."""
        # counting first: checking every robot on each hello would be O(n^2) per fleet
        return len(self._online) >= n and all(r in self._online for r in range(n))

    def robot(self, r: int) -> GatewaySession:
        """The protocol session of robot ``r`` (created on first use)."""
        gs = self.robots.get(r)
        if gs is None:
            gs = self.robots[r] = GatewaySession(r)
        return gs

    # -------------------------------------------------------------------------- the loop
    async def run(self) -> None:
        """Process queue items forever; tick while running. Each tick is an item that a loop
        timer queues at its time (one timer per tick, not one armed and cancelled per
        wake-up of this task)."""
        self._resumed = time.thread_time()
        while True:
            ticking = self.current_run.ticking
            if not ticking:
                self._stop_ticking()
            elif self._tick_item is None:
                self._arm_tick(self._first_tick(self.now_ms()))
            if self.queue.empty():
                self.commit()
                item = await self._get()
                if self._batch_s:
                    await self._gather()
            else:
                if self._commit_due():
                    self.commit()
                item = self.queue.get_nowait()
            if item is self._tick_item:
                await self._tick_at(self._tick_ms)
                continue
            self._handled += 1
            if not self._handled & 63:  # a gauge: a sample every 64 items is enough
                self.metrics.queue_depth.set(self.queue.qsize())
            self._handle_safely(item)
            self._uncommitted += 1

    async def _gather(self) -> None:
        """Woken by an item less than ``batch_ms`` after the last batch began: let the items
        queue until then, to be handled as one batch (one commit, one write to each worker).
        Nothing is waiting to be committed meanwhile (this follows a commit)."""
        loop = asyncio.get_running_loop()
        wait = self._batch_at + self._batch_s - loop.time()
        if wait > 0:
            for hold in self.holding:
                hold(True)
            try:
                await self._waiting(asyncio.sleep(wait))
            finally:
                for hold in self.holding:
                    hold(False)
            if self.holding:
                # what was held is queued in the next turn (its reads follow this task's step)
                await self._waiting(asyncio.sleep(0))
                await self._waiting(asyncio.sleep(0))
        self._batch_at = loop.time()

    def _arm_tick(self, at_ms: float) -> None:
        """Queue a tick item at plan time ``at_ms``."""
        self._tick_ms = at_ms
        item = self._tick_item = OwnerCall(_tick_marker)
        delay = (at_ms - self.clock.now_ms()) / self.clock.speed / 1000.0
        self._tick_timer = asyncio.get_running_loop().call_later(
            max(0.0, delay), self.queue.put_nowait, item)

    def _stop_ticking(self) -> None:
        """No more ticks (a tick item already queued is then a no-op call)."""
        if self._tick_timer is not None:
            self._tick_timer.cancel()
        self._tick_timer = self._tick_item = None

    async def _tick_at(self, t_ms: float) -> None:
        """The tick due at ``t_ms``: once the instant is quiet, the hooks, then the monitor;
        then the next tick is armed."""
        await self._quiesce()
        for hook in self.before_tick:
            hook(t_ms)
        await self._quiesce()
        self._tick_safely()
        self._arm_tick(self._next_tick(t_ms))

    def _commit_due(self) -> bool:
        """A group commit is full: :data:`GROUP_COMMIT_ITEMS` items handled since the last
        commit (commit before handling more, even with the queue still non-empty)."""
        return self._uncommitted >= GROUP_COMMIT_ITEMS

    async def _get(self) -> Item:
        """The next queue item."""
        return await self._waiting(self.queue.get())

    async def _waiting(self, awaited: Awaitable[_T]) -> _T:
        """``await awaited``; with :attr:`meter_cpu`, the owner's CPU time is not counted
        while it waits."""
        if not self.meter_cpu:
            return await awaited
        self.cpu_s += time.thread_time() - self._resumed
        try:
            return await awaited
        finally:
            self._resumed = time.thread_time()

    async def _quiesce(self) -> None:
        """Handle everything of the present instant, including what the replies to it cause
        (a finish -> a dispatch -> the robot's start), before a tick looks at the monitor."""
        while True:
            self.commit()
            await self._waiting(self.clock.settle())
            if self.queue.empty():
                return
            while not self.queue.empty():
                self._handle_safely(self.queue.get_nowait())

    def commit(self) -> None:
        """Make what was journaled durable, then write the trace records it caused (called
        before the owner task yields: nothing queued for a peer leaves before this)."""
        self._uncommitted = 0
        for hook in self.before_commit:
            hook()
        if self.journal is not None:
            t0 = time.perf_counter()
            if self.journal.commit():  # (a wake-up for acks and states alone writes none)
                self.metrics.journal_commit.observe(time.perf_counter() - t0)
        self.feed.flush_trace()
        for hook in self.after_commit:
            hook()

    def _first_tick(self, now: float) -> float:
        """When ticking begins (a start, a resume): now if the core's wake-up is already due
        (a resumed shift's planning call is not put off to the next period), else the next
        tick."""
        core = self._core()
        wake = core.next_wakeup_ms() if core is not None else None
        return now if wake is not None and wake <= now else self._next_tick(now)

    def _next_tick(self, after: float) -> float:
        period = float(MONITOR_PERIOD_MS)
        t = (math.floor(after / period) + 1) * period
        core = self._core()  # a shift's planning call is due at its own time, not a tick's
        wake = core.next_wakeup_ms() if core is not None else None
        return min(t, wake) if wake is not None and wake > after else t

    def _handle_safely(self, item: Item) -> None:
        try:
            self._handle(item)
        except Exception:  # never let one bad item kill the owner task
            log.exception("internal error handling %s", type(item).__name__)
            if isinstance(item, Inbound):
                item.session.error(ErrorCode.INTERNAL, item.message.msg_id, "internal error")

    def _handle(self, item: Item) -> None:
        if isinstance(item, RobotReports):
            self._robot_reports(item)
        elif isinstance(item, Inbound):
            self._inbound(item)
        elif isinstance(item, Connected):
            self._connected(item.session)
        elif isinstance(item, Disconnected):
            self._disconnected(item.session)
        elif isinstance(item, InternalCommand):
            self.operator.handle(item.message, item.reply)
        elif isinstance(item, OwnerCall):
            item.fn()
        else:
            self._solver_done(item)

    def _tick_safely(self) -> None:
        """Tick; an internal error is logged (once until a tick succeeds again) and the owner
        task lives on: a silently dead owner task would stall the whole fleet."""
        try:
            self._tick()
        except Exception:
            if not self._tick_failing:
                log.exception("internal error in the monitor tick")
            self._tick_failing = True
        else:
            self._tick_failing = False

    def _tick(self) -> None:
        self.current_run.monitor_tick(self.now_ms())

    # -------------------------------------------------------------------------- connections
    def _connected(self, session: Session) -> None:
        role = session.peer.role
        self.metrics.connections.labels(role).inc()
        if role == "operator":
            self.feed.operators.add(session)
            self.send_snapshot(session)
        elif role == "world":
            self.worlds.add(session)
            session.send(SetSpeed, speed=self.clock.speed)

    def _disconnected(self, session: Session) -> None:
        peer = session.peer
        self.metrics.connections.labels(peer.role).dec()
        self.feed.operators.discard(session)
        self.worlds.discard(session)
        r = peer.robot_id
        if r is not None and r in self.robots and self.robots[r].disconnected(session):
            self._online.discard(r)
            self.metrics.connected_robots.dec()
            self.feed.event("connection", self.clock.now_ms(), robot=r, state="off")
            log.info("robot disconnected", extra={"robot": r})

    # -------------------------------------------------------------------------- inbound
    def _inbound(self, item: Inbound) -> None:
        msg, session = item.message, item.session
        match msg:  # the most frequent first: two reports and an ack per action
            case Started() | Finished() | Blocked() | Unblocked() | Cancelled() \
                    | ActionRefused():
                reason = f"{msg.code}: {msg.detail}" if isinstance(msg, ActionRefused) else ""
                self._report(session, msg.type, msg.action_id, msg.msg_id, msg.pose,
                             item.received, item.at_ms, reason)
            case Ack():
                self._ack(session, msg.action_id, msg.msg_id)
            case Hello():
                self._hello(session, msg)
            case State():
                self._sender(session).state(msg.pose, session)
            case IntruderReport():
                self._intruder(session, msg, self._arrival_ms(item.at_ms))
            case _:
                self.operator.handle(msg, session)  # type: ignore[arg-type]

    def _robot_reports(self, item: RobotReports) -> None:
        """What a worker process passed on as :class:`RobotReports`, in order (an internal
        error in one is logged and answered; the others are handled)."""
        self._uncommitted += len(item.reports) - 1  # (a group commit counts reports)
        at_ms = item.at_ms
        for session, kind, aid, ref, pose, received in item.reports:
            try:
                if kind == "state":
                    self._sender(session).state(pose, session)
                elif kind == "ack":
                    self._ack(session, aid, ref)
                else:
                    self._report(session, cast(ReportKind, kind), aid, ref, pose, received,
                                 at_ms)
            except Exception:  # as _handle_safely: never let one bad report kill the owner
                log.exception("internal error handling a robot report")
                session.error(ErrorCode.INTERNAL, ref or None, "internal error")

    def _ack(self, session: Session, aid: str, ref: str) -> None:
        gs = self._sender(session)
        gs.ack(aid, ref, session)
        self.flush(gs, session)

    def _sender(self, session: Session) -> GatewaySession:
        """The protocol session of the robot a connection speaks for."""
        r = session.peer.robot_id
        assert r is not None, "only robots send robot messages"
        return self.robot(r)

    def _hello(self, session: Session, msg: Hello) -> None:
        r = msg.robot_id
        session.version = msg.v  # answer in the robot's protocol version
        refusal = hello_refusal(msg, self.current_run.turning)
        if refusal is not None:
            session.error(ErrorCode.UNSUPPORTED_VERSION, msg.msg_id, refusal)
            session.close(CloseCode.POLICY, "protocol v1 robot on a turning plan")
            return
        gs = self.robot(r)
        old = gs.link
        if old is not None:  # a reconnect, or a second hello on this connection
            if old is not session:
                cast(Session, old).close(4000, "replaced by a new connection of the same robot")
            self._online.discard(r)
            self.metrics.connected_robots.dec()
        now = self.now_ms()
        running = self._core() is not None
        gs.hello(msg, now, run=self.run_id if running else None,
                 plan=self.current_run.plan_id)
        self.flush(gs, session)  # catch-ups; what they unlock is held for the resend
        resent = gs.welcome(session, version=session.version, start=self.current_run.pose(r),
                            plan=self.current_run.plan_id,
                            state_period_ms=self.config.state_period_ms, paused=self.paused)
        self.flush(gs, session)
        self._online.add(r)
        self.metrics.connected_robots.inc()
        self.feed.event("connection", now, robot=r, state="on")
        log.info("robot connected", extra={"robot": r, "resent": resent})
        self.operator.maybe_autostart()

    def _report(self, session: Session, kind: ReportKind, aid: str, ref: str,
                pose: Pose | None, received: float, at_ms: float | None, reason: str = ""
                ) -> None:
        """A robot's report about action ``aid`` (``ref``: the report's msg_id)."""
        gs = self._sender(session)
        now = self._arrival_ms(at_ms)
        try:
            self._unlocked_at = received if kind == "finished" else None
            gs.report(kind, aid, ref, session, now, pose, reason)
            self.flush(gs, session)
        finally:
            self._unlocked_at = None

    def _arrival_ms(self, at_ms: float | None) -> float:
        """The plan time at which a message that arrived at ``at_ms`` takes effect: its arrival,
        but never before the executor's last input (trace records stay in time order)."""
        ex = self._core()
        return self.now_ms() if at_ms is None or ex is None else max(at_ms, ex.now_ms)

    def flush(self, gs: GatewaySession, sender: Session | None = None) -> None:
        """Carry out a robot session's effects: messages to its connection, refusals to the
        ``sender`` of the message being handled, reports to the executor. A flush of the same
        session nested in this one (an effect's dispatch) leaves the rest to this loop, so the
        session's effects are carried out in the order it queued them."""
        if gs.robot_id in self._flushing:
            return
        self._flushing.add(gs.robot_id)
        try:
            self._flush(gs, sender)
        finally:
            self._flushing.discard(gs.robot_id)

    def _flush(self, gs: GatewaySession, sender: Session | None) -> None:
        while effects := gs.drain():
            for e in effects:
                if isinstance(e, ToRobot):
                    link = cast(Session | None, gs.link)
                    if link is not None and e.kind is Action:
                        link.send_action(e.fields)
                    elif link is not None:
                        link.send(e.kind, **e.fields)
                elif isinstance(e, Refuse):
                    if sender is not None:
                        sender.error(e.code, e.ref, e.detail)
                else:
                    self._apply(gs, e)

    def _apply(self, gs: GatewaySession, r: Report) -> None:
        """Feed one robot report to the executor; tell the session whether it was taken."""
        ex = self._core()
        if ex is None:
            gs.rejected(r, "no execution is running")
            return
        # the core's method of the same name (refused: with the robot's reason)
        apply: Callable[[int, int, int, float], None] = (
            partial(ex.refused, reason=r.reason) if r.kind == "refused"
            else getattr(ex, r.kind))
        try:  # (a catch-up applied after later inputs takes effect at the latest of them)
            apply(r.robot, r.plan, r.index, max(r.t_ms, ex.now_ms))
        except ExecutionError as exc:
            if r.ref is None:
                log.warning("hello: cannot apply %s of %s: %s", r.kind, r.action_id, exc)
            gs.rejected(r, str(exc))
            return
        gs.accepted(r)
        if r.kind == "finished":
            self.metrics.finished_pending += 1
        elif r.kind == "refused":
            log.warning("robot refused an action", extra={
                "robot": r.robot, "action": r.action_id, "reason": r.reason})
        self.current_run.route()

    def _intruder(self, session: Session, msg: IntruderReport, now: float) -> None:
        """Record a world's intruder report (trace and operators) at plan time ``now`` if it is
        consistent: a free cell of the loaded map, on only if it is off and off only if it is on."""
        cell = (int(msg.cell[0]), int(msg.cell[1]))
        if self.problem is not None and not self.problem.instance.grid.is_free(cell):
            session.error(ErrorCode.REJECTED, msg.msg_id, f"{list(cell)} is not a free cell")
            return
        if (cell in self.feed.intruders) == (msg.state == "on"):
            session.error(ErrorCode.DUPLICATE, msg.msg_id,
                          f"the intruder on {list(cell)} is already {msg.state}")
            return
        if self.executor is not None and self.journal is not None:
            self.journal.append(IntruderRecord(t_ms=now, cell=cell, state=msg.state))
        self.feed.intruder(now, cell, msg.state)

    # -------------------------------------------------------------------------- routing
    def route(self, commands: list[Command]) -> None:
        """Turn executor commands into messages and planner calls, in the order the executor
        gave them. Routing one may feed the executor (a dispatch of an action the robot said
        it finished applies that finish: a journal that lost its last records), whose new
        commands are then routed after the rest of this batch, never before: a session gets
        its robot's actions in dispatch order (else a robot's listed finish of an action
        released by a nested batch would be refused as queued behind one of this batch)."""
        if not commands:  # (most reports release nothing)
            return
        if self._routing:
            self._routed_later.extend(commands)
            return
        self._routing = True
        try:
            for c in commands:
                self._route(c)
            while self._routed_later:
                self._route(self._routed_later.popleft())
        finally:
            self._routing = False
            self._routed_later.clear()  # (left only by an error: its batch ends there)

    def _route(self, c: Command) -> None:
        """Carry out one executor command."""
        if isinstance(c, Dispatch):
            self._dispatch(c)
        elif isinstance(c, Cancel):
            gs = self.robot(c.robot)
            gs.cancel(action_id(c.plan, c.robot, c.action, self.run_id))
            self.flush(gs)
        elif isinstance(c, Trigger):
            self.metrics.replans.inc()
            log.info("replan triggered", extra={"policy": c.policy,
                                                "fleet_slack_ms": c.fleet_slack_ms})
            self.status_changed()
        elif isinstance(c, SolveRequest):
            assert self.problem is not None
            if self.replaying:
                return  # solved once the replay is over, if still unanswered
            hs = c.headings
            starts: Sequence[Place] = c.starts if hs is None else [
                (x, y, h) for (x, y), h in zip(c.starts, hs, strict=True)]
            self.solvers.spawn("shadow" if c.shadow else "replan", self.problem, starts,
                               c.goals, None, None, "omni" if hs is None else "turning",
                               c.forbidden(self.now_ms(), self.config.action_ms))
        elif isinstance(c, Rescheduled):
            log.info("rescheduled", extra={"switches": len(c.switches),
                                           "gain_ms": round(c.gain_ms, 1)})
        elif isinstance(c, PlanAdopted):
            for gs in self.robots.values():
                gs.plan_adopted()
            self.status_changed()
        elif isinstance(c, Completed):
            self._completed(c)

    def _dispatch(self, c: Dispatch) -> None:
        aid = action_id(c.plan, c.robot, c.action, self.run_id)
        # plain JSON values: the session writes them as they are (encode_action)
        fields: dict[str, Any] = {
            "action_id": aid, "sequence": int(c.action),
            "src": _pose(c.src, c.src_heading), "dst": _pose(c.dst, c.dst_heading),
            "duration_ms": float(c.duration_ms),
        }
        gs = self.robot(c.robot)
        gs.dispatch(fields)
        self.flush(gs)
        self.metrics.dispatched_pending += 1
        if self._unlocked_at is not None:
            latency = (time.perf_counter() - self._unlocked_at) * 1000.0
            self.latencies_ms.append(latency)
            self.metrics.latency.observe(latency / 1000.0)

    def _completed(self, c: Completed) -> None:
        self.summary = (c.soc_ms, c.makespan_ms)
        summary = summary_record(c.soc_ms, c.makespan_ms)
        self.feed.write_trace(summary)
        if self.replaying:
            self.replayed_trace.append(trace_line(summary))
            self.finished_event.set()
            return
        self.feed.close_trace()
        self.feed.event("summary", self.now_ms(), soc_ms=c.soc_ms,
                              makespan_ms=c.makespan_ms)
        self.status_changed()
        self.finished_event.set()
        log.info("execution complete", extra={"soc_ms": c.soc_ms, "makespan_ms": c.makespan_ms})

    def _solver_done(self, item: SolverDone) -> None:
        self.metrics.planner_call.labels(item.purpose).observe(item.wall_ms / 1000.0)
        if item.purpose == "load":
            self.operator.load_solved(item)
            return
        self.current_run.solver_done(item)

    def load(self, problem: Problem) -> None:
        """Plan ``problem`` (unless it has a plan) and make it the loaded one."""
        self.operator.load(problem)

    # -------------------------------------------------------------------------- resume
    def resume(self) -> bool:
        """Rebuild the journaled run, if there is one, and carry on with it (robots are
        re-synchronised by their ``hello``); True if a journaled run goes on."""
        return self.current_run.resume()

    def replayed_report(self, rec: ReportRecord) -> None:
        """A report the replayed core took: the robot's session takes it too."""
        aid = action_id(rec.plan, rec.robot, rec.index, self.run_id)
        self.robot(rec.robot).accepted(Report(rec.event, rec.robot, rec.plan, rec.index, aid,
                                              rec.t_ms, None, rec.reason))

    # -------------------------------------------------------------------------- outputs
    def status_changed(self) -> None:
        """Tell operators and status listeners what the gateway is doing now."""
        status = self.status
        self.feed.event("status", self.clock.now_ms(), status=status)
        for listener in self.status_listeners:
            listener(status)

    def send_snapshot(self, session: Session) -> None:
        """Send the whole fleet state to one operator."""
        session.send(Snapshot, **snapshot_fields(self.read_model()))

    def read_model(self) -> FleetView:
        """What operators are shown, read-only (see :mod:`gateway.server.views`)."""
        feed = self.feed
        return FleetView(
            t_ms=self.now_ms(), max_replans=self.config.max_replans, status=self.status,
            threshold_ms=self.threshold_ms,
            policy=self.policy_name, speed=self.clock.speed, slack_series=feed.slack_series,
            intruders=feed.intruders, replan_marks=feed.replan_marks, problem=self.problem,
            executor=self.executor, robots=self.robots, worlds=len(self.worlds),
            shift=self.current_run.shift_view)

    async def aclose(self) -> None:
        """Cancel running planner tasks and close the trace."""
        self.solvers.cancel_all()
        self._stop_ticking()
        self.current_run.cancel()
        self.commit()
        self.feed.close_trace()
