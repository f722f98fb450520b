"""The owner task: the only code that touches the :class:`Executor` (single writer, no locks).

Connection handlers only validate messages and put them on :attr:`Engine.queue`; the owner
task (:meth:`Engine.run`) takes one item at a time, feeds the executor with the clock's time,
and routes what the executor drains into the sessions' send queues. It also ticks the executor
every ``MONITOR_PERIOD_MS`` while running, and runs the planner off-loop (the clock decides how)
while events keep queueing; the result comes back as a queue item.

Robot bookkeeping kept here (the executor knows none of it): which actions each robot holds
(dispatched, not finished or cancelled), which it acknowledged, and which were applied, so a
second ``finished`` is refused as a duplicate and a reconnecting robot is resent what it holds.
"""

from __future__ import annotations

import asyncio
import contextlib
import gc
import json
import logging
import math
import time
from collections import deque
from collections.abc import Callable, Sequence
from typing import IO, Any, Literal

from gateway.execution.actions import ActionDurations
from gateway.execution.commands import (
    Cancel,
    Command,
    Completed,
    Dispatch,
    PlanAdopted,
    SolveRequest,
    Trigger,
)
from gateway.execution.executor import MONITOR_PERIOD_MS, ExecutionError, Executor, Mode
from gateway.execution.policies import ReplanPolicy, SlackReplan, make_policy
from gateway.execution.trace_records import intruder_record, summary_record
from gateway.planning.grid import Cell
from gateway.planning.motion import Motion
from gateway.planning.plan import NoSolution, Plan
from gateway.planning.solver import Place
from gateway.server.clock import Clock
from gateway.server.config import GatewayConfig
from gateway.server.items import (
    Connected,
    Disconnected,
    Inbound,
    InternalCommand,
    Item,
    Reply,
    SolverDone,
)
from gateway.server.metrics import Metrics
from gateway.server.planner import (
    InstanceError,
    Problem,
    plan_for,
    problem_from_paths,
    resolve_instance,
)
from gateway.server.robots import Held, RobotRecord
from gateway.server.session import Session
from gateway.server.views import snapshot_fields
from protocol import (
    Ack,
    Action,
    Blocked,
    CancelAction,
    Cancelled,
    ErrorCode,
    Event,
    Finished,
    GetSnapshot,
    Hello,
    IntruderReport,
    LoadInstance,
    LoadPlan,
    Ok,
    OperatorCommand,
    Pause,
    PlaceIntruder,
    Pose,
    ReplanNow,
    Resume,
    SetPolicy,
    SetSpeed,
    SetThreshold,
    Snapshot,
    Start,
    Started,
    State,
    Unblocked,
    Welcome,
    action_id,
    parse_action_id,
)
from protocol.messages import HEADINGS, GatewayStatus, PolicyName

log = logging.getLogger("fleetgate.engine")

ReportKind = Literal["started", "finished", "blocked", "unblocked", "cancelled"]

GC_THRESHOLDS = (100_000, 50, 100)
"""The process's garbage-collector thresholds once a run starts (Python's default: 700, 10,
10): a young-generation pass after 100,000 net new container objects instead of 700."""
GC_DEFAULT_THRESHOLDS = gc.get_threshold()
"""The thresholds restored when a run is complete."""


class CommandError(Exception):
    """An operator command is refused with ``code``."""

    def __init__(self, code: ErrorCode, detail: str) -> None:
        super().__init__(detail)
        self.code = code
        self.detail = detail


# ------------------------------------------------------------------------------ the engine
class Engine:
    """Executor owner: robot/operator/world bookkeeping, routing, ticks, planning."""

    def __init__(self, config: GatewayConfig, clock: Clock, metrics: Metrics) -> None:
        self.config = config
        self.clock = clock
        self.metrics = metrics
        self.queue: asyncio.Queue[Item] = asyncio.Queue()
        self.problem: Problem | None = None
        self.executor: Executor | None = None
        self.planning = False
        self.paused = False
        self.robots: dict[int, RobotRecord] = {}
        self._online: set[int] = set()  # robots with a live session (O(1) autostart check)
        self.operators: set[Session] = set()
        self.worlds: set[Session] = set()
        self.policy_name: PolicyName = config.policy
        self.policy_seed = config.policy_seed
        self.threshold_ms = config.threshold_ms
        self.slack_series: deque[tuple[float, float]] = deque(maxlen=config.slack_series_len)
        self.replan_marks: list[dict[str, Any]] = []
        """The current run's replans for operators (fields of protocol.ReplanMark)."""
        self.intruders: set[Cell] = set()
        self.latencies_ms: list[float] = []
        self.summary: tuple[float, float] | None = None
        self.finished_event = asyncio.Event()
        self._trace: IO[str] | None = None
        self._tasks: set[asyncio.Task[None]] = set()
        self._unlocked_at: float | None = None  # perf_counter of the finish being applied
        self.status_listeners: list[Callable[[GatewayStatus], None]] = []
        self.before_tick: list[Callable[[float], None]] = []
        """Called with the tick's time once the instant is quiet, just before each monitor
        tick (a simulated world in the same process steps its intruder here, in the order of
        the discrete-event driver: robot events, then the world, then the tick)."""
        self.solver_ms = 0.0  # planner time charged for replans of the current run

    # -------------------------------------------------------------------------- status
    @property
    def status(self) -> GatewayStatus:
        """What the gateway is doing."""
        if self.planning:
            return "planning"
        ex = self.executor
        if ex is None:
            return "loaded" if self.problem is not None and self.problem.plan else "empty"
        if ex.mode is Mode.DONE:
            return "done"
        if self.paused:
            return "paused"
        if ex.mode in (Mode.STOPPING, Mode.SOLVING):
            return "replanning"
        return "running"

    def now_ms(self) -> float:
        """The present for the executor (never before its last input)."""
        now = self.clock.now_ms()
        return max(now, self.executor.now_ms) if self.executor is not None else now

    def connected_robots(self) -> int:
        """How many robots are connected (said hello on a live connection)."""
        return len(self._online)

    def robot(self, r: int) -> RobotRecord:
        """The record of robot ``r`` (created on first use)."""
        rec = self.robots.get(r)
        if rec is None:
            rec = self.robots[r] = RobotRecord()
        return rec

    # -------------------------------------------------------------------------- the loop
    async def run(self) -> None:
        """Process queue items forever; tick while running."""
        next_tick: float | None = None
        while True:
            ticking = self.executor is not None and self.executor.mode is not Mode.DONE
            if not ticking:
                next_tick = None
                item = await self.queue.get()
            else:
                if next_tick is None:
                    next_tick = self._next_tick(self.now_ms())
                if not self.queue.empty():
                    # what ``get`` under the timeout would return at once, without arming and
                    # cancelling a timer per item (a busy fleet keeps this queue non-empty)
                    item = self.queue.get_nowait()
                else:
                    delay = (next_tick - self.clock.now_ms()) / self.clock.speed / 1000.0
                    try:
                        async with asyncio.timeout(max(0.0, delay)):
                            item = await self.queue.get()
                    except TimeoutError:
                        await self._quiesce()
                        for hook in self.before_tick:
                            hook(next_tick)
                        await self._quiesce()
                        self._tick()
                        next_tick = self._next_tick(next_tick)
                        continue
            self.metrics.queue_depth.set(self.queue.qsize())
            self._handle_safely(item)

    async def _quiesce(self) -> None:
        """Handle everything of the present instant, including what the replies to it cause
        (a finish -> a dispatch -> the robot's start), before a tick looks at the monitor."""
        while True:
            await self.clock.settle()
            if self.queue.empty():
                return
            while not self.queue.empty():
                self._handle_safely(self.queue.get_nowait())

    def _next_tick(self, after: float) -> float:
        period = float(MONITOR_PERIOD_MS)
        t = (math.floor(after / period) + 1) * period
        wake = self.executor.next_wakeup_ms() if self.executor is not None else None
        return min(t, wake) if wake is not None and wake > after else t

    def _handle_safely(self, item: Item) -> None:
        try:
            self._handle(item)
        except Exception:  # never let one bad item kill the owner task
            log.exception("internal error handling %s", type(item).__name__)
            if isinstance(item, Inbound):
                item.session.error(ErrorCode.INTERNAL, item.message.msg_id, "internal error")

    def _handle(self, item: Item) -> None:
        if isinstance(item, Inbound):
            self._inbound(item)
        elif isinstance(item, Connected):
            self._connected(item.session)
        elif isinstance(item, Disconnected):
            self._disconnected(item.session)
        elif isinstance(item, InternalCommand):
            self._command(item.message, item.reply)
        else:
            self._solver_done(item)

    def _tick(self) -> None:
        ex = self.executor
        if ex is None or ex.mode is Mode.DONE:
            return  # while paused the monitor is kept true (the executor asks no policy)
        now = self.now_ms()
        ex.tick(now)
        slack = ex.monitor.fleet_slack()
        self.metrics.fleet_slack.set(slack)
        if not self.slack_series or self.slack_series[-1][1] != slack \
                or now - self.slack_series[-1][0] >= 1000.0:
            self.slack_series.append((now, slack))
            self._broadcast_event("slack", now, fleet_slack_ms=slack)
        self._route(ex.drain())

    # -------------------------------------------------------------------------- connections
    def _connected(self, session: Session) -> None:
        role = session.peer.role
        self.metrics.connections.labels(role).inc()
        if role == "operator":
            self.operators.add(session)
            self.send_snapshot(session)
        elif role == "world":
            self.worlds.add(session)
            session.send(SetSpeed, speed=self.clock.speed)

    def _disconnected(self, session: Session) -> None:
        peer = session.peer
        self.metrics.connections.labels(peer.role).dec()
        self.operators.discard(session)
        self.worlds.discard(session)
        if peer.robot_id is not None:
            rec = self.robot(peer.robot_id)
            if rec.session is session:
                rec.session = None
                self._online.discard(peer.robot_id)
                self.metrics.connected_robots.dec()
                self._broadcast_event("connection", self.clock.now_ms(), robot=peer.robot_id,
                                      state="off")
                log.info("robot disconnected", extra={"robot": peer.robot_id})

    # -------------------------------------------------------------------------- inbound
    def _inbound(self, item: Inbound) -> None:
        msg, session = item.message, item.session
        match msg:
            case Hello():
                self._hello(session, msg)
            case Ack():
                self._ack(session, msg.action_id, msg.msg_id)
            case Started() | Finished() | Blocked() | Unblocked() | Cancelled():
                self._report(session, msg, item.received, item.at_ms)
            case State():
                r = self._robot_of(session)
                if r is not None and msg.pose is not None:
                    self.robot(r).pose = msg.pose
            case IntruderReport():
                self._intruder(session, msg)
            case _:
                self._command(msg, session)  # type: ignore[arg-type]

    def _robot_of(self, session: Session) -> int | None:
        """The robot a session speaks for, if it said hello and was not replaced since."""
        r = session.peer.robot_id
        if r is None or self.robot(r).session is not session:
            return None
        return r

    def _hello(self, session: Session, msg: Hello) -> None:
        r = msg.robot_id
        session.version = msg.v  # answer in the robot's protocol version
        plan = self.executor.plan if self.executor is not None else (
            self.problem.plan if self.problem is not None else None)
        if msg.v < 2 and plan is not None and plan.headings is not None:
            session.error(ErrorCode.UNSUPPORTED_VERSION, msg.msg_id,
                          "the plan is for turning robots: protocol v2 needed (a v1 robot "
                          "moves omni-directionally)")
            session.close(1008, "protocol v1 robot on a turning plan")
            return
        rec = self.robot(r)
        if rec.session is not None:  # a reconnect, or a second hello on this connection
            if rec.session is not session:
                rec.session.close(4000, "replaced by a new connection of the same robot")
            self.metrics.connected_robots.dec()
        rec.session = None  # dispatches unlocked below are resent in the welcome
        self._online.discard(r)
        if msg.pose is not None:
            rec.pose = msg.pose
        now = self.now_ms()
        for aid in msg.finished:
            if aid in rec.held:
                self._catch_up(r, rec, aid, "finished", now)
        running = msg.current.action_id if msg.current and msg.current.state == "running" \
            else None
        if msg.current is not None and msg.current.action_id in rec.held:
            h = rec.held[msg.current.action_id]
            if msg.current.state == "running" and h.phase != "running":
                self._catch_up(r, rec, msg.current.action_id, "started", now)
            elif msg.current.state == "blocked" and h.phase == "dispatched":
                self._catch_up(r, rec, msg.current.action_id, "blocked", now)
        for aid, h in list(rec.held.items()):
            if h.cancel and h.phase != "running" and aid != running:
                self._catch_up(r, rec, aid, "cancelled", now)
        if self.executor is not None:
            self._route(self.executor.drain())  # unlocked actions go into the resend list
        rec.session = session
        self._online.add(r)
        self.metrics.connected_robots.inc()
        resend = [Action(v=session.version, msg_id=f"resend-{aid}", seq=0, **h.fields)
                  for aid, h in rec.held.items()]
        session.send(Welcome, robot_id=r, start=self._start_pose(r),
                     plan=self.executor.plan_id if self.executor else None, resend=resend,
                     state_period_ms=self.config.state_period_ms, paused=self.paused)
        for aid, h in rec.held.items():
            if h.cancel:
                session.send(CancelAction, action_id=aid)
        self._broadcast_event("connection", now, robot=r, state="on")
        log.info("robot connected", extra={"robot": r, "resent": len(resend)})
        self._maybe_autostart()

    def _start_pose(self, r: int) -> Pose | None:
        plan = self.executor.plan if self.executor is not None else (
            self.problem.plan if self.problem is not None else None)
        if plan is None or r >= len(plan.paths):
            return None
        return Pose(cell=plan.paths[r][0])

    def _catch_up(self, r: int, rec: RobotRecord, aid: str, kind: ReportKind,
                  now: float) -> None:
        """Apply what a reconnecting robot reports it did while it was away."""
        try:
            if kind == "finished" and rec.held[aid].phase != "running":
                self._apply(r, rec, aid, "started", now)
            self._apply(r, rec, aid, kind, now)
        except ExecutionError as exc:
            log.warning("hello: cannot apply %s of %s: %s", kind, aid, exc)

    def _ack(self, session: Session, aid: str, ref: str) -> None:
        r = self._robot_of(session)
        if r is None:
            session.error(ErrorCode.BAD_STATE, ref, "say hello first")
            return
        rec = self.robot(r)
        if aid in rec.held:
            rec.held[aid].acked = True
        elif aid not in rec.applied:
            session.error(ErrorCode.UNKNOWN_ACTION, ref,
                          f"action {aid} was never dispatched to robot {r}")

    def _report(self, session: Session,
                msg: Started | Finished | Blocked | Unblocked | Cancelled,
                received: float, at_ms: float | None = None) -> None:
        kind: ReportKind = msg.type
        r = self._robot_of(session)
        if r is None:
            session.error(ErrorCode.BAD_STATE, msg.msg_id, "say hello first")
            return
        rec = self.robot(r)
        if msg.pose is not None:
            rec.pose = msg.pose
        aid: str = msg.action_id
        if aid in rec.applied:
            session.error(ErrorCode.DUPLICATE, msg.msg_id,
                          f"{kind} of {aid}: the action was already {rec.applied[aid]}")
            return
        held = rec.held.get(aid)
        if held is None or self.executor is None:
            session.error(ErrorCode.UNKNOWN_ACTION, msg.msg_id,
                          f"{kind} of {aid}: never dispatched to robot {r}")
            return
        if (kind, held.phase) in (("started", "running"), ("blocked", "blocked")):
            session.error(ErrorCode.DUPLICATE, msg.msg_id, f"{aid} is already {held.phase}")
            return
        try:
            self._unlocked_at = received if kind == "finished" else None
            now = self.now_ms() if at_ms is None else max(at_ms, self.executor.now_ms)
            self._apply(r, rec, aid, kind, now, on_the_way=session.version >= 2)
            self._route(self.executor.drain())
        except ExecutionError as exc:
            session.error(ErrorCode.REJECTED, msg.msg_id, str(exc))
        finally:
            self._unlocked_at = None

    def _apply(self, r: int, rec: RobotRecord, aid: str, kind: ReportKind, now: float,
               on_the_way: bool = False) -> None:
        """Feed one robot event to the executor and update the robot's record; with
        ``on_the_way`` (protocol v2) a ``blocked`` of a running move is a stop on the way."""
        ex = self.executor
        assert ex is not None
        plan, _, index = parse_action_id(aid)
        held = rec.held[aid]
        if kind == "started":
            ex.started(r, plan, index, now)
            held.phase = "running"
        elif kind == "blocked":
            if on_the_way and held.phase == "running":
                ex.stopped(r, plan, index, now)
            else:
                ex.blocked(r, plan, index, now)
            held.phase = "blocked"
        elif kind == "unblocked":
            ex.unblocked(r, plan, index, now)
            held.phase = "running" if ex.has_started(r, plan, index) else "dispatched"
        elif kind == "finished":
            ex.finished(r, plan, index, now)
            del rec.held[aid]
            rec.applied[aid] = "finished"
            rec.next_index = max(rec.next_index, index + 1)
            self.metrics.finished.inc()
        else:
            ex.cancelled(r, plan, index, now)
            del rec.held[aid]
            rec.applied[aid] = "cancelled"

    def _intruder(self, session: Session, msg: IntruderReport) -> None:
        """Record a world's intruder report (trace and operators) if it is consistent: a free
        cell of the loaded map, on only if it is off and off only if it is on."""
        cell = (int(msg.cell[0]), int(msg.cell[1]))
        if self.problem is not None and not self.problem.instance.grid.is_free(cell):
            session.error(ErrorCode.REJECTED, msg.msg_id, f"{list(cell)} is not a free cell")
            return
        if (cell in self.intruders) == (msg.state == "on"):
            session.error(ErrorCode.DUPLICATE, msg.msg_id,
                          f"the intruder on {list(cell)} is already {msg.state}")
            return
        if msg.state == "on":
            self.intruders.add(cell)
        else:
            self.intruders.discard(cell)
        now = self.clock.now_ms()
        self._write_trace(intruder_record(now, cell, msg.state))
        self._broadcast_event("intruder", now, cell=cell, state=msg.state)

    # -------------------------------------------------------------------------- routing
    def _route(self, commands: list[Command]) -> None:
        """Turn executor commands into messages and planner calls."""
        for c in commands:
            if isinstance(c, Dispatch):
                self._dispatch(c)
            elif isinstance(c, Cancel):
                aid = action_id(c.plan, c.robot, c.action)
                rec = self.robot(c.robot)
                if aid in rec.held:
                    rec.held[aid].cancel = True
                if rec.session is not None:
                    rec.session.send(CancelAction, action_id=aid)
            elif isinstance(c, Trigger):
                self.metrics.replans.inc()
                log.info("replan triggered", extra={"policy": c.policy,
                                                    "fleet_slack_ms": c.fleet_slack_ms})
                self._status_changed()
            elif isinstance(c, SolveRequest):
                assert self.problem is not None
                hs = c.headings
                starts: Sequence[Place] = c.starts if hs is None else [
                    (x, y, h) for (x, y), h in zip(c.starts, hs, strict=True)]
                self._spawn_solver("replan", self.problem, starts, c.goals, None, None,
                                   "omni" if hs is None else "turning")
            elif isinstance(c, PlanAdopted):
                for rec in self.robots.values():
                    rec.next_index = 0
                self._status_changed()
            elif isinstance(c, Completed):
                self._completed(c)

    def _dispatch(self, c: Dispatch) -> None:
        aid = action_id(c.plan, c.robot, c.action)
        fields: dict[str, Any] = {
            "action_id": aid, "sequence": c.action,
            "src": Pose(cell=c.src, heading=None if c.src_heading is None
                        else HEADINGS[c.src_heading]),
            "dst": Pose(cell=c.dst, heading=None if c.dst_heading is None
                        else HEADINGS[c.dst_heading]),
            "duration_ms": c.duration_ms,
        }
        rec = self.robot(c.robot)
        rec.held[aid] = Held(fields)
        self.metrics.dispatched.inc()
        if rec.session is not None:
            rec.session.send(Action, **fields)
        if self._unlocked_at is not None:
            latency = (time.perf_counter() - self._unlocked_at) * 1000.0
            self.latencies_ms.append(latency)
            self.metrics.latency.observe(latency / 1000.0)

    def _completed(self, c: Completed) -> None:
        gc.unfreeze()
        gc.set_threshold(*GC_DEFAULT_THRESHOLDS)
        self.summary = (c.soc_ms, c.makespan_ms)
        self._write_trace(summary_record(c.soc_ms, c.makespan_ms))
        self._close_trace()
        self._broadcast_event("summary", self.now_ms(), soc_ms=c.soc_ms,
                              makespan_ms=c.makespan_ms)
        self._status_changed()
        self.finished_event.set()
        log.info("execution complete", extra={"soc_ms": c.soc_ms, "makespan_ms": c.makespan_ms})

    # -------------------------------------------------------------------------- planning
    def _spawn_solver(self, purpose: Literal["load", "replan"], problem: Problem,
                      starts: Sequence[Place], goals: tuple[Cell, ...], reply: Reply,
                      ref: str | None, motion: Motion) -> None:
        grid, limit = problem.instance.grid, self.config.solver_time_limit_s

        def work() -> Plan:
            return plan_for(grid, starts, goals, limit, self.config.fallback_s, motion)

        async def run() -> None:
            t0 = time.perf_counter()
            try:
                result: Plan | Exception
                result, charged = await self.clock.run_solver(work)
                if purpose == "replan":
                    self.solver_ms += charged
            except (NoSolution, ValueError) as exc:
                result = exc
            wall = (time.perf_counter() - t0) * 1000.0
            self.queue.put_nowait(SolverDone(purpose, result, problem, reply, ref, wall))

        task = asyncio.get_running_loop().create_task(run(), name=f"solver-{purpose}")
        self._tasks.add(task)
        task.add_done_callback(self._tasks.discard)

    def _solver_done(self, item: SolverDone) -> None:
        if item.purpose == "replan":
            ex = self.executor
            if ex is None or ex.mode is not Mode.SOLVING:
                return  # a new run was started meanwhile
            now = self.now_ms()
            if isinstance(item.result, Plan):
                ex.adopt_plan(item.result, now)
            else:
                log.warning("replan found no plan, keeping the old one: %s", item.result)
                ex.abandon_replan(now)
            self._route(ex.drain())
            return
        self.planning = False
        assert item.problem is not None
        if isinstance(item.result, Plan):
            self.problem = Problem(item.problem.instance, item.problem.map_name, item.result)
            self._reply(item.reply, item.ref, None,
                        f"loaded {item.problem.map_name}: {len(item.result.paths)} robots, "
                        f"SOC {item.result.soc}, makespan {item.result.makespan}")
            self._loaded()
        else:
            self._reply(item.reply, item.ref, ErrorCode.BAD_REQUEST,
                        f"no plan for this instance: {item.result}")
            self._status_changed()

    # -------------------------------------------------------------------------- operator
    def _command(self, msg: OperatorCommand, reply: Reply) -> None:
        try:
            detail = self._execute(msg, reply)
        except CommandError as exc:
            self._reply(reply, msg.msg_id, exc.code, exc.detail)
            return
        if detail is not None:
            self._reply(reply, msg.msg_id, None, detail)

    def _reply(self, reply: Reply, ref: str | None, code: ErrorCode | None,
               detail: str) -> None:
        if isinstance(reply, Session):
            if code is None:
                reply.send(Ok, ref=ref or "", detail=detail)
            else:
                reply.error(code, ref, detail)
        elif reply is not None and not reply.done():
            reply.set_result((code, detail))

    def _idle(self, what: str) -> None:
        if self.planning or self.status in ("running", "paused", "replanning"):
            raise CommandError(ErrorCode.BAD_STATE, f"cannot {what} while {self.status}")

    def _execute(self, msg: OperatorCommand, reply: Reply) -> str | None:
        """Carry out a command; returns the Ok detail, or None if the reply comes later."""
        match msg:
            case LoadInstance():
                self._idle("load an instance")
                if msg.scen is not None and msg.generate is not None:
                    raise CommandError(ErrorCode.BAD_REQUEST, "give scen or generate, not both")
                seed = msg.generate.seed if msg.generate else self.config.generate_seed
                try:
                    problem = resolve_instance(msg.map, msg.scen, msg.agents, seed)
                except InstanceError as exc:
                    raise CommandError(ErrorCode.BAD_REQUEST, str(exc)) from None
                self.load(problem, reply, msg.msg_id)
                return None
            case LoadPlan():
                self._idle("load a plan")
                try:
                    problem = problem_from_paths(msg.map, msg.paths, msg.headings)
                except InstanceError as exc:
                    raise CommandError(ErrorCode.BAD_REQUEST, str(exc)) from None
                self.executor = None
                self.problem = problem
                self._loaded()
                return f"loaded a plan for {len(msg.paths)} robots"
            case Start():
                self.start()
                return "started"
            case Pause():
                if self.status not in ("running", "replanning"):
                    raise CommandError(ErrorCode.BAD_STATE, f"cannot pause while {self.status}")
                self._set_paused(True)
                return "paused"
            case Resume():
                if not self.paused:
                    raise CommandError(ErrorCode.BAD_STATE, f"cannot resume while {self.status}")
                self._set_paused(False)
                return "resumed"
            case ReplanNow():
                if self.executor is None or self.paused:
                    raise CommandError(ErrorCode.BAD_STATE, f"cannot replan while {self.status}")
                try:
                    self.executor.request_replan(self.now_ms())
                except ExecutionError as exc:
                    raise CommandError(ErrorCode.BAD_STATE, str(exc)) from None
                self._route(self.executor.drain())
                return "replanning"
            case SetPolicy():
                self.policy_name, self.policy_seed = msg.policy, msg.seed
                if self.executor is not None:
                    self.executor.policy = self._make_policy(self.executor.plan)
                self._status_changed()
                return f"policy {self.policy_name}"
            case SetThreshold():
                self.threshold_ms = msg.threshold_ms
                if self.executor is not None and isinstance(self.executor.policy, SlackReplan):
                    self.executor.policy.threshold_ms = self.threshold_ms
                self._status_changed()
                return f"threshold {self.threshold_ms} ms"
            case SetSpeed():
                self.clock.set_speed(msg.speed)
                for w in self.worlds:
                    w.send(SetSpeed, speed=msg.speed)
                self._status_changed()
                return f"speed {msg.speed}"
            case PlaceIntruder():
                if not self.worlds:
                    raise CommandError(ErrorCode.BAD_STATE, "no world connection to place it")
                if self.problem is not None and not self.problem.instance.grid.is_free(msg.cell):
                    raise CommandError(ErrorCode.BAD_REQUEST, f"{msg.cell} is not a free cell")
                for w in self.worlds:
                    w.send(PlaceIntruder, cell=msg.cell, duration_ms=msg.duration_ms)
                return f"intruder sent to {len(self.worlds)} world connection(s)"
            case GetSnapshot():
                if isinstance(reply, Session):
                    self.send_snapshot(reply)
                    return None
                return "snapshot"
        raise CommandError(ErrorCode.FORBIDDEN, f"{msg.type} is not an operator command")

    def _set_paused(self, paused: bool) -> None:
        self.paused = paused
        ex = self.executor
        if ex is not None and ex.paused != paused:
            (ex.pause if paused else ex.resume)(self.now_ms())
            self._route(ex.drain())
        for rec in self.robots.values():
            if rec.session is not None:
                if paused:
                    rec.session.send(Pause, reason="operator")
                else:
                    rec.session.send(Resume)
        self._status_changed()

    def _durations(self, robots: int) -> list[ActionDurations]:
        """Each robot's t_x per action kind: its configured model, else ``action_ms``."""
        cfg = self.config
        models = {name: ActionDurations(m.move_ms, m.turn_ms, m.wait_ms)
                  for name, m in cfg.robot_models.items()}
        uniform = ActionDurations.uniform(cfg.action_ms)
        return [models[cfg.robot_model[k]] if k in cfg.robot_model else uniform
                for k in range(robots)]

    def _make_policy(self, plan: Plan) -> ReplanPolicy:
        return make_policy(self.policy_name, seed=self.policy_seed,
                           threshold_ms=self.threshold_ms,
                           makespan_lb_ms=plan.makespan * self.config.action_ms)

    def load(self, problem: Problem, reply: Reply = None, ref: str | None = None) -> None:
        """Plan ``problem`` (unless it has a plan) and make it the loaded one."""
        self.executor = None
        if problem.plan is not None:
            self.problem = problem
            self._loaded()
            self._reply(reply, ref, None, "loaded")
            return
        self.planning = True
        self._status_changed()
        inst, motion = problem.instance, self.config.motion
        starts = inst.starts if motion == "omni" else inst.turning_starts(
            self.config.start_heading)
        self._spawn_solver("load", problem, starts, inst.goals, reply, ref, motion)

    def _loaded(self) -> None:
        for rec in self.robots.values():
            rec.held.clear()
            rec.applied.clear()
            rec.next_index = 0
            rec.pose = None  # where it stood in the previous world
        self.slack_series.clear()
        self.summary = None
        self._status_changed()
        for op in self.operators:
            self.send_snapshot(op)
        self._maybe_autostart()

    def _maybe_autostart(self) -> None:
        if not self.config.autostart or self.status != "loaded" or self.problem is None:
            return
        n = self.problem.instance.num_agents
        # counting first: checking every robot on each hello would be O(n^2) per fleet
        if len(self._online) >= n and all(r in self._online for r in range(n)):
            self.start()

    def start(self) -> None:
        """Start executing the loaded plan from time 0."""
        if self.problem is None or self.problem.plan is None or self.status not in (
                "loaded", "done"):
            raise CommandError(ErrorCode.BAD_STATE, f"cannot start while {self.status}")
        plan = self.problem.plan
        for rec in self.robots.values():
            rec.held.clear()
            rec.applied.clear()
            rec.next_index = 0
        self.slack_series.clear()
        self.replan_marks.clear()
        self.summary = None
        self.solver_ms = 0.0
        self.finished_event.clear()
        self.paused = False
        self._open_trace()
        self.executor = Executor(plan, policy=self._make_policy(plan),
                                 action_ms=self.config.action_ms,
                                 drop_waits=self.config.drop_waits,
                                 max_replans=self.config.max_replans, record=self._record,
                                 lookahead=self.config.dispatch_lookahead,
                                 durations=self._durations(len(plan.paths)))
        # The plan, ADG, monitor and connections live as long as the run: move them out of
        # the cyclic collector's reach, or its full passes over a large fleet's objects stall
        # the owner (~150 ms at 2,000 robots). Only what exists now is frozen; what the run
        # allocates later is collected, but rarely (GC_THRESHOLDS): nearly all of it is freed
        # by reference counting, and with the default thresholds the collector ran every 700
        # allocations, ~25 % of the gateway's CPU and 30-60 ms pauses at 2,000 robots.
        # The tuning lasts for the run only (undone in _completed): collect first, so that no
        # garbage of an earlier run is frozen, and a gateway serving many runs does not grow.
        gc.collect()
        gc.freeze()
        gc.set_threshold(*GC_THRESHOLDS)
        self.clock.reset()  # time 0 is now: building the ADG and the GC pass are not charged
        self.executor.start(0.0)
        self._status_changed()
        self._route(self.executor.drain())

    # -------------------------------------------------------------------------- outputs
    def _record(self, rec: dict[str, object]) -> None:
        """The executor's trace records: to the trace file and to operators as events."""
        self._write_trace(rec)
        t_ms: Any = rec["t_ms"]
        kind = str(rec["type"])
        if kind == "trigger":
            self.replan_marks.append({"trigger_ms": float(t_ms), "policy": str(rec["policy"])})
        elif kind == "plan" and rec.get("plan") and self.replan_marks:
            self.replan_marks[-1].update(plan=rec["plan"], adopted_ms=float(t_ms))
        if not self.operators:
            return  # several records per action: build no event nobody would receive
        fields: dict[str, Any] = {k: v for k, v in rec.items()
                                  if k not in ("type", "t_ms", "agents", "motion")}
        agents: Any = rec.get("agents")
        if agents is not None:
            fields["paths"] = [[c[:2] for c in a["path"]] for a in agents]
            if rec.get("motion") == "turning":
                fields["headings"] = [[c[2] for c in a["path"]] for a in agents]
        self._broadcast_event(kind, float(t_ms), **fields)

    def _broadcast_event(self, kind: str, t_ms: float, **fields: Any) -> None:
        for op in list(self.operators):
            op.send(Event, event=kind, t_ms=t_ms, **fields)

    def _status_changed(self) -> None:
        status = self.status
        self._broadcast_event("status", self.clock.now_ms(), status=status)
        for listener in self.status_listeners:
            listener(status)

    def _open_trace(self) -> None:
        self._close_trace()
        if self.config.trace is not None:
            self._trace = self.config.trace.open("w")

    def _write_trace(self, rec: dict[str, object]) -> None:
        if self._trace is not None:
            self._trace.write(json.dumps(rec) + "\n")

    def _close_trace(self) -> None:
        if self._trace is not None:
            with contextlib.suppress(OSError):
                self._trace.close()
            self._trace = None

    def send_snapshot(self, session: Session) -> None:
        """Send the whole fleet state to one operator."""
        session.send(Snapshot, **snapshot_fields(self))

    async def aclose(self) -> None:
        """Cancel running planner tasks and close the trace."""
        for task in list(self._tasks):
            task.cancel()
        self._close_trace()
