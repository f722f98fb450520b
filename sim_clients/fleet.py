"""Simulated robots that speak protocol v1 to a gateway over any transport, many per process.

Every robot of a :class:`SimFleet` is the sans-I/O :class:`~sim_clients.robot.SimRobot` of the
discrete-event driver, driven by timers of the running event loop: it checks its target cell
in the fleet's one shared :class:`~sim_clients.world.World`; the protocol (acknowledgements,
duplicates, the action queue, cancel, pause, the ``hello`` of a reconnect) is the shared
:class:`~protocol.robot_session.RobotSession`, the same as the real robot's. A robot sends a
``state`` every ``state_period_ms`` and reconnects when its link drops. A fleet may also open
the "world" connection: it receives ``place_intruder`` (and ``set_speed``) and reports
``intruder`` on/off.

Time: robots read plan time from a :class:`~gateway.server.clock.LoopClock` (the gateway's own
in one process, so both agree on "now" and on ``speed``). The automatic intruder of DESIGN
section 2 needs the monitor's estimates at ``T_a`` (:class:`IntruderOracle`), which only an
in-process driver can give; :meth:`SimFleet.poll_world` then runs due intruder work, and an
in-process driver calls it at the gateway's monitor ticks after every robot event of that
instant (the order of the discrete-event driver). Without that, the fleet polls on its own.
"""

from __future__ import annotations

import asyncio
import contextlib
import itertools
import logging
import random
import ssl
import time
from collections.abc import Awaitable, Callable, Iterable, Sequence
from dataclasses import dataclass, field
from typing import Any, Protocol, TypeVar, cast

from websockets.exceptions import ConnectionClosed, InvalidMessage, InvalidStatus

from gateway.execution.commands import Dispatch
from gateway.planning.grid import Cell
from gateway.planning.plan import Path
from gateway.planning.seeds import run_seed
from gateway.server.clock import LoopClock
from gateway.server.engine import Engine
from gateway.server.gateway import Gateway
from gateway.server.planner import Problem
from protocol import (
    Action,
    AnyMessage,
    Error,
    Finished,
    IntruderReport,
    PlaceIntruder,
    Pose,
    ProtocolError,
    SetSpeed,
    Start,
    Welcome,
    action_id,
    decode,
    encode,
    parse_action_id,
)
from protocol.messages import HEADINGS, PROTOCOL_VERSION, Heading, ProtocolVersion
from protocol.robot_session import (
    Abort,
    GatewayError,
    Received,
    Refused,
    ReportKind,
    RobotEffect,
    RobotSession,
    Send,
    Welcomed,
)
from sim_clients.intruder import Intruder, IntruderConfig, IntruderState, pick_target_at
from sim_clients.robot import RECHECK_MS, RobotEvent, RobotState, SimRobot
from sim_clients.summary import RunSummary
from sim_clients.world import World

log = logging.getLogger("fleetgate.sim")

M = TypeVar("M", bound=AnyMessage)


class ClientConnection(Protocol):
    """What both a websockets client connection and the in-memory client offer."""

    async def send(self, message: str) -> None:
        """Send one text frame."""
        ...

    async def recv(self) -> str | bytes:
        """The next frame; raises ``websockets.ConnectionClosed`` once closed."""
        ...

    async def close(self, code: int = 1000, reason: str = "") -> None:
        """Close the connection."""
        ...


Connect = Callable[[str], Awaitable[ClientConnection]]
"""Opens an authenticated connection for a token (a websocket or ``Gateway.connect``)."""


def demo_robot_token(robot: int) -> str:
    """The loopback demo token of robot ``robot`` (the gateway's default prefix)."""
    return f"demo-robot-{robot}"


class IntruderOracle(Protocol):
    """What the automatic intruder reads from the executor at ``T_a`` (in-process only)."""

    @property
    def running(self) -> bool:
        """True once an execution started (before that, there is nothing to read)."""
        ...

    @property
    def plan_id(self) -> int:
        """Number of the plan being executed."""
        ...

    def paths(self) -> Sequence[Path]:
        """The current plan's paths."""
        ...

    def start_ms(self, robot: int, action: int) -> float:
        """The monitor's estimated start of action ``action`` of ``robot``."""
        ...

    def completion_ms(self, robot: int, action: int) -> float:
        """The monitor's estimated completion of action ``action`` of ``robot``."""
        ...


@dataclass
class FleetStats:
    """What the robots saw: for latency, loss and duplicate accounting (perf_counter s)."""

    received: dict[str, float] = field(default_factory=dict)
    """First arrival of every action id."""
    finish_sent: dict[str, float] = field(default_factory=dict)
    """When each action's ``finished`` was handed to the connection."""
    duplicates: int = 0
    reconnects: int = 0
    errors: list[str] = field(default_factory=list)
    """``code: detail`` of every ``error`` a robot was sent."""


def transient(exc: BaseException) -> bool:
    """Whether a failed connection attempt is worth repeating (LIVE-1: a robot whose link is
    lost reconnects): nobody listening, a connection reset, a gateway that went away in the
    middle of the handshake (it answered no valid HTTP response: e.g. it stopped on a journal
    failure just as the robot reconnected), or a 5xx answer. A refused token (401, 403) or
    another 4xx is not."""
    if isinstance(exc, InvalidStatus):
        return exc.response.status_code >= 500
    return isinstance(exc, OSError | ConnectionClosed | InvalidMessage | EOFError)


class FleetRobot:
    """One simulated robot and its connection: a :class:`SimRobot` body driven by the shared
    protocol session (:class:`~protocol.robot_session.RobotSession`)."""

    def __init__(self, fleet: SimFleet, robot_id: int) -> None:
        self.fleet = fleet
        self.robot_id = robot_id
        self.sim: SimRobot | None = None
        self.session = RobotSession(robot_id, repeat_finished=not fleet.must_only,
                                    version=fleet.protocol)
        self.connected = asyncio.Event()
        self.plan = -1
        """Plan of the latest started action (with :attr:`next_action`: first not started)."""
        self.next_action = 0
        self._ids: dict[tuple[int, int], str] = {}  # (plan, index) -> action id, while it runs
        self._conn: ClientConnection | None = None
        self._outbox: asyncio.Queue[str | None] = asyncio.Queue()
        self._timer: asyncio.TimerHandle | None = None
        self._state_timer: asyncio.TimerHandle | None = None
        self._rng = random.Random(f"{fleet.seed}/{robot_id}")  # state phase, duration jitter

    # ------------------------------------------------------------------ placement
    @property
    def cell(self) -> Cell | None:
        """Where the robot stands (None until it was placed)."""
        return self.sim.cell if self.sim is not None else None

    def unplace(self) -> None:
        """Take the robot out of the world (its cells are freed, its timer dropped)."""
        sim = self.sim
        if sim is not None:
            d = sim.current
            if sim.state is RobotState.MOVING and d is not None and d.dst != d.src:
                self.fleet.world.release(d.dst, self.robot_id)
            self.fleet.world.release(sim.cell, self.robot_id)
            self.sim = None
        if self._timer is not None:
            self._timer.cancel()
            self._timer = None

    def place(self, pose: Pose) -> None:
        """Put the robot on ``pose`` (cell, and heading under ``turning``) for a new run:
        forget every action of the previous one."""
        self.unplace()
        world = self.fleet.world
        world.occupy(pose.cell, self.robot_id, self.fleet.clock.now_ms())
        self.sim = SimRobot(self.robot_id, world, pose.cell, recheck_ms=self.fleet.recheck_ms,
                            heading=_heading_number(pose.heading))
        self._ids.clear()
        self.session.reset()
        self.session.pose = pose
        self.plan, self.next_action = -1, 0

    # ------------------------------------------------------------------ connection
    async def run(self) -> None:
        """Connect, say hello, serve the connection; reconnect until the fleet stops."""
        fleet = self.fleet
        while not fleet.stopping:
            try:
                conn = await fleet.connect(fleet.token(self.robot_id))
            except ssl.SSLError as exc:  # verification failed: retrying will not help
                fleet.fail(f"robot {self.robot_id}: TLS: {exc.reason or exc}")
                return
            except Exception as exc:
                if not transient(exc):  # e.g. its token refused: retrying will not help
                    fleet.fail(f"robot {self.robot_id}: cannot connect: {exc}")
                    return
                log.info("robot %d cannot connect: %s", self.robot_id, exc)
                fleet.unreachable(exc)
                await asyncio.sleep(fleet.reconnect_delay_s)
                continue
            self._conn = conn
            writer = asyncio.create_task(self._write(conn))
            try:
                self.session.connected(self._pose())
                self._pump()
                await self._read(conn)
            except ConnectionClosed:
                pass
            finally:
                self._conn = None
                self.session.disconnected()
                self.connected.clear()
                self._outbox.put_nowait(None)
                await writer
                with contextlib.suppress(Exception):
                    await conn.close()
            if not fleet.stopping:
                fleet.stats.reconnects += 1
                await asyncio.sleep(fleet.reconnect_delay_s)

    async def drop_link(self) -> None:
        """Close the current connection abruptly (tests: the robot reconnects by itself)."""
        if self._conn is not None:
            await self._conn.close(1011, "simulated link loss")

    def _pose(self) -> Pose | None:
        sim = self.sim
        if sim is None:
            return None
        return Pose(cell=sim.cell, heading=None if sim.heading is None else HEADINGS[sim.heading])

    async def _write(self, conn: ClientConnection) -> None:
        while True:
            text = await self._outbox.get()
            if text is None:
                return
            with contextlib.suppress(ConnectionClosed):
                await conn.send(text)

    async def _read(self, conn: ClientConnection) -> None:
        while True:
            raw = await conn.recv()
            try:
                msg = decode(raw)
            except ProtocolError as exc:
                self.fleet.stats.errors.append(f"robot {self.robot_id} got a bad message: {exc}")
                continue
            self._before(msg)
            self.session.receive(msg)
            self._pump()

    def _before(self, msg: AnyMessage) -> None:
        """Place the robot before the session takes ``msg``: at its start on a first welcome,
        and afresh when a new run's first action arrives."""
        if isinstance(msg, Welcome):
            if self.sim is None and msg.start is not None:
                self.place(msg.start)
            actions = msg.resend
        else:
            actions = [msg] if isinstance(msg, Action) else []
        for action in actions:
            if action.sequence == 0 and parse_action_id(action.action_id)[0] == 0 \
                    and self._new_run(action):
                self.place(action.src)

    def _new_run(self, action: Action) -> bool:
        """A first action of plan 0 arriving after this robot did anything, or before it was
        placed, starts a new run (the operator loaded and started another instance)."""
        s = self.session
        return self.sim is None or (
            self.sim.current is None and bool(s.finished or s.queue)
            and not s.knows(action.action_id))

    # ------------------------------------------------------------------ session effects
    def _pump(self) -> None:
        """Start what may start, and carry out the session's effects until there are none."""
        while True:
            self._feed()
            effects = self.session.drain()
            if not effects:
                return
            for effect in effects:
                self._effect(effect)

    def _effect(self, effect: RobotEffect) -> None:
        stats = self.fleet.stats
        match effect:
            case Send(message=msg):
                if self._conn is not None:
                    self._outbox.put_nowait(encode(msg))
                    if isinstance(msg, Finished):
                        stats.finish_sent[msg.action_id] = time.perf_counter()
            case Received(action=action, duplicate=duplicate):
                if duplicate:
                    stats.duplicates += 1
                else:
                    stats.received.setdefault(action.action_id, time.perf_counter())
            case Welcomed():
                self.connected.set()
                self.fleet.on_connected(self.robot_id)
                if self.fleet.send_state:
                    self._schedule_state(first=True)
            case Abort(action_id=aid):
                sim = self.sim
                if sim is not None and sim.current is not None:
                    plan, _, index = parse_action_id(aid)
                    sim.cancel(plan, index, self._now())  # its "cancelled" is the session's
                    self._reschedule()
            case GatewayError(error=err):
                stats.errors.append(f"robot {self.robot_id}: {err.code}: {err.detail}")
            case Refused(action=action, reason=reason):
                stats.errors.append(f"robot {self.robot_id} refused {action.action_id}: "
                                    f"{reason}")

    def _schedule_state(self, first: bool = False) -> None:
        """The next ``state`` report; the first at a random phase of the period, so that a
        fleet that connected at once does not report all at once."""
        if self._state_timer is not None:
            self._state_timer.cancel()
        period = self.session.state_period_ms * (self._rng.random() if first else 1.0)
        delay = period / self.fleet.clock.speed / 1000.0

        def fire() -> None:
            self._state_timer = None
            if self._conn is None or self.fleet.stopping:
                return
            self.session.state(self._pose())
            self._pump()
            self._schedule_state()

        self._state_timer = asyncio.get_running_loop().call_later(delay, fire)

    # ------------------------------------------------------------------ the body
    def _feed(self) -> None:
        """Hand the next action to the robot if it is idle and the session lets it start."""
        sim = self.sim
        if sim is None or sim.state is not RobotState.IDLE:
            return
        action = self.session.take()
        if action is None:
            return
        plan, robot, index = parse_action_id(action.action_id)
        src_heading = _heading_number(action.src.heading)
        if sim.cell != tuple(action.src.cell) or (
                None not in (src_heading, sim.heading) and src_heading != sim.heading):
            self.session.refuse_current("pose_mismatch", (
                f"it starts at {list(action.src.cell)} facing {action.src.heading}, but the "
                f"robot is on {list(sim.cell)} facing {sim.heading}"), self._pose())
            self._pump()
            return
        d = Dispatch(plan, robot, index, action.src.cell, action.dst.cell, action.duration_ms,
                     src_heading, _heading_number(action.dst.heading))
        self._ids[(plan, index)] = action.action_id  # the id carries the run: report with it
        if self.fleet.on_event is not None:
            self.fleet.on_event("execute", plan, robot, index)
        jitter = self.fleet.duration_jitter
        extra = action.duration_ms * self._rng.uniform(-jitter, jitter) if jitter else 0.0
        self._emit(sim.dispatch(d, self._now(), extra))
        self._reschedule()

    def _now(self) -> float:
        return self.fleet.clock.now_ms()

    def _reschedule(self) -> None:
        if self._timer is not None:
            self._timer.cancel()
            self._timer = None
        sim = self.sim
        due = sim.next_wakeup_ms() if sim is not None else None
        if due is None:
            return
        clock = self.fleet.clock
        delay = max(0.0, (due - clock.now_ms()) / clock.speed / 1000.0)
        self._timer = asyncio.get_running_loop().call_later(delay, self._wake, due)

    def _wake(self, due: float) -> None:
        self._timer = None
        sim = self.sim
        if sim is None or self.fleet.stopping:
            return
        self._emit(sim.wake(max(due, self._now())))
        self._reschedule()
        self._pump()

    def _emit(self, events: list[RobotEvent]) -> None:
        pose = self._pose()
        for e in events:
            if e.kind == "started" and e.plan >= self.plan:
                self.plan, self.next_action = e.plan, e.action + 1
            if self.fleet.on_event is not None:
                self.fleet.on_event(e.kind, e.plan, e.robot, e.action)
            aid = self._ids.get((e.plan, e.action)) or action_id(e.plan, e.robot, e.action)
            if e.kind in ("finished", "cancelled"):
                self._ids.pop((e.plan, e.action), None)
            self.session.report(cast(ReportKind, e.kind), aid, pose)


def _heading_number(heading: Heading | None) -> int | None:
    """A plan's heading number of a protocol heading (None stays None)."""
    return None if heading is None else HEADINGS.index(heading)


class SimFleet:
    """Many simulated robots on one shared :class:`World`, plus the "world" connection.

    ``robots`` are the robot ids to run; ``connect(token)`` opens a connection. ``clock``
    should be the gateway's clock when both run in one process. ``duration_jitter`` makes
    action durations vary (seeded per robot). ``oracle`` enables the
    automatic intruder (DESIGN section 2: appears at ``intruder_config.appear_ms``); its
    random choices use ``seed`` exactly as the discrete-event driver does.
    """

    def __init__(self, connect: Connect, robots: Iterable[int], *,
                 token: Callable[[int], str] = demo_robot_token,
                 clock: LoopClock | None = None, world_token: str | None = None,
                 oracle: IntruderOracle | None = None, seed: int = 0,
                 intruder_config: IntruderConfig | None = None,
                 recheck_ms: float = RECHECK_MS, reconnect_delay_s: float = 0.2,
                 send_state: bool = True, external_poll: bool = False,
                 duration_jitter: float = 0.0, must_only: bool = False,
                 protocol: ProtocolVersion = PROTOCOL_VERSION) -> None:
        if not 0.0 <= duration_jitter < 1.0:
            raise ValueError(f"duration_jitter must be in [0, 1), got {duration_jitter}")
        self.connect = connect
        self.seed = seed
        self.duration_jitter = duration_jitter
        """Each action lasts its duration x U(1 - j, 1 + j) (0: exactly; a real fleet's
        robots are never in lockstep)."""
        self.token = token
        self.clock = clock if clock is not None else LoopClock()
        self.world = World()
        self.recheck_ms = recheck_ms
        self.reconnect_delay_s = reconnect_delay_s
        self.send_state = send_state
        self.must_only = must_only
        self.protocol: ProtocolVersion = protocol
        """The protocol version the robots speak (3: no ``ack``)."""
        """Robots that implement only the protocol's MUST rules (no repeated ``finished`` for a
        duplicate of a finished action: a MAY of DUP-1)."""
        self.stats = FleetStats()
        self.on_event: Callable[[str, int, int, int], None] | None = None
        """Called with (kind, plan, robot, index) when a robot takes an action to execute it
        (kind "execute") and at each event of its body ("started", "finished", ...):
        benchmarks count double executions and completions with it."""
        self.stopping = False
        self.robots: dict[int, FleetRobot] = {}
        self._world_token = world_token
        self._world_conn: ClientConnection | None = None
        self._world_seq = itertools.count()
        self._world_ready = asyncio.Event()
        self._oracle = oracle
        self._intruder_config = intruder_config or IntruderConfig()
        self._rng = random.Random(run_seed(seed, "intruder"))
        # the automatic intruder (absent until T_a), then any the operator places
        self._intruders: list[Intruder] = (
            [Intruder(self.world, self._intruder_config)] if oracle is not None else [])
        self._external_poll = external_poll
        self._tasks: list[asyncio.Task[None]] = []
        self._all_connected = asyncio.Event()
        self._welcomed: set[int] = set()  # robots that got a welcome at least once
        self._failure: str | None = None
        self._ids = list(robots)
        self.connect_error: str | None = None
        """Why the first connection attempt that found nobody failed (see :meth:`unreachable`)."""
        self.gateway_absent = asyncio.Event()

    # ------------------------------------------------------------------ lifecycle
    async def start(self) -> None:
        """Start every robot (and the world connection) in the background."""
        loop = asyncio.get_running_loop()
        if self._world_token is not None:
            self._tasks.append(loop.create_task(self._run_world(), name="sim-world"))
            try:  # robots move at the gateway's speed: learn it before they can get actions
                async with asyncio.timeout(10.0):
                    await self._world_ready.wait()
            except TimeoutError:
                log.warning("no set_speed from the gateway on the world connection yet")
        for r in self._ids:
            self.add_robot(r)
        if not self._ids:  # only the world (e.g. the robots are VDA 5050 vehicles)
            self._all_connected.set()
        if not self._external_poll:
            self._tasks.append(loop.create_task(self._poll_loop(), name="sim-intruders"))

    def add_robot(self, r: int) -> FleetRobot:
        """Run robot ``r`` too (no-op if it runs already)."""
        if r in self.robots:
            return self.robots[r]
        robot = self.robots[r] = FleetRobot(self, r)
        self._tasks.append(asyncio.get_running_loop().create_task(robot.run(), name=f"sim-{r}"))
        return robot

    async def wait_connected(self, timeout: float | None = None) -> None:
        """Until every robot got its first ``welcome`` (and the world connection is up)."""
        async with asyncio.timeout(timeout):
            await self._all_connected.wait()
            if self._world_token is not None:
                await self._world_ready.wait()
        if self._failure is not None:
            raise RuntimeError(self._failure)

    def on_connected(self, robot_id: int) -> None:
        """Robot ``robot_id`` was welcomed (counts each robot once; O(1), not a scan of the
        fleet per welcome)."""
        self._welcomed.add(robot_id)
        if len(self._welcomed) >= len(self.robots):
            self._all_connected.set()

    def fail(self, reason: str) -> None:
        """Stop waiting: a robot (or the world connection) cannot run at all."""
        self._failure = reason
        log.error(reason)
        self._all_connected.set()
        self._world_ready.set()

    def unreachable(self, exc: BaseException) -> None:
        """A connection attempt found nobody there (it is retried): the first reason is kept
        in :attr:`connect_error` and :attr:`gateway_absent` is set."""
        if self.connect_error is None:
            self.connect_error = str(exc) or type(exc).__name__
        self.gateway_absent.set()

    async def stop(self) -> None:
        """Stop every robot and close the connections."""
        self.stopping = True
        for robot in self.robots.values():
            if robot._conn is not None:
                with contextlib.suppress(Exception):
                    await robot._conn.close()
        if self._world_conn is not None:
            with contextlib.suppress(Exception):
                await self._world_conn.close()
        for task in self._tasks:
            task.cancel()
        await asyncio.gather(*self._tasks, return_exceptions=True)

    def rearm_intruder(self) -> None:
        """A new run: the automatic intruder comes again, at ``T_a`` of that run (if the fleet
        has one; one that never appeared in the last run is not doubled)."""
        if self._oracle is not None:
            self._intruders = [i for i in self._intruders if i.state is not IntruderState.ABSENT]
            self._intruders.append(Intruder(self.world, self._intruder_config))

    def place_all(self, starts: Sequence[Cell], headings: Sequence[int] | None = None) -> None:
        """Put robot k on ``starts[k]`` (facing ``headings[k]`` under ``turning``) for a new
        run (other robots leave the world)."""
        for robot in self.robots.values():
            robot.unplace()
        for k, cell in enumerate(starts):
            if k in self.robots:
                heading = None if headings is None else HEADINGS[headings[k]]
                self.robots[k].place(Pose(cell=cell, heading=heading))

    # ------------------------------------------------------------------ the world
    async def _run_world(self) -> None:
        assert self._world_token is not None
        while not self.stopping:
            try:
                conn = await self.connect(self._world_token)
            except ssl.SSLError as exc:
                self.fail(f"the world connection: TLS: {exc.reason or exc}")
                return
            except Exception as exc:
                if not transient(exc):
                    self.fail(f"the world connection: cannot connect: {exc}")
                    return
                self.unreachable(exc)
                await asyncio.sleep(self.reconnect_delay_s)
                continue
            self._world_conn = conn
            try:
                while True:
                    try:
                        msg = decode(await conn.recv())
                    except ProtocolError as exc:
                        self.stats.errors.append(f"world got a bad message: {exc}")
                        continue
                    if isinstance(msg, SetSpeed):
                        if msg.speed != self.clock.speed:
                            self.clock.set_speed(msg.speed)
                        self._world_ready.set()
                    elif isinstance(msg, PlaceIntruder):
                        self.place_intruder((msg.cell[0], msg.cell[1]), msg.duration_ms)
                    elif isinstance(msg, Error):
                        self.stats.errors.append(f"world: {msg.code}: {msg.detail}")
            except ConnectionClosed:
                self._world_conn = None
            if not self.stopping:
                await asyncio.sleep(self.reconnect_delay_s)

    def place_intruder(self, cell: Cell, duration_ms: float) -> None:
        """An operator's intruder: on ``cell`` as soon as it is free, for ``duration_ms``."""
        now = self.clock.now_ms()
        intruder = Intruder(self.world, IntruderConfig(appear_ms=now,
                                                       leave_ms=now + duration_ms))
        self._report(intruder.appear(now, (-1, cell)))
        self._intruders.append(intruder)

    def poll_world(self, now_ms: float | None = None) -> None:
        """Run every intruder step due at ``now_ms`` (default: now)."""
        now = self.clock.now_ms() if now_ms is None else now_ms
        for intr in self._intruders:
            due = intr.next_wakeup_ms()
            if due is None or due > now:
                continue
            if intr.state is IntruderState.ABSENT:
                if self._oracle is None or not self._oracle.running:
                    continue  # the run has not started: T_a is counted from its start
                target = self._auto_target(now)
                self._report(intr.appear(now, None if target is None else target[:2],
                                         None if target is None else target[2]))
            else:
                self._report(intr.wake(now))
        self._intruders = [i for i in self._intruders if i.state is not IntruderState.GONE]

    def _auto_target(self, now: float) -> tuple[int, Cell, float] | None:
        oracle = self._oracle
        assert oracle is not None
        plan_id = oracle.plan_id
        next_action = [0] * len(oracle.paths())
        for k in range(len(next_action)):
            robot = self.robots.get(k)
            if robot is not None and robot.plan == plan_id:
                next_action[k] = robot.next_action
        config = self._intruder_config
        visit = oracle.start_ms if config.reading == "start" else oracle.completion_ms
        return pick_target_at(self._rng, oracle.paths(), next_action, visit,
                              now + config.lead_ms)

    async def _poll_loop(self) -> None:
        """Poll the intruders at every multiple of ``recheck_ms`` (when no driver does it)."""
        step = self.recheck_ms
        while not self.stopping:
            t = (self.clock.now_ms() // step + 1) * step
            await self.clock.sleep_until_ms(t)
            self.poll_world()

    def _report(self, events: Iterable[Any]) -> None:
        for e in events:
            if self._world_conn is None:
                continue
            seq = next(self._world_seq)
            text = encode(IntruderReport(msg_id=f"w-{seq}", seq=seq, cell=e.cell,
                                         state=e.state))
            task = asyncio.get_running_loop().create_task(self._world_send(text))
            self._tasks.append(task)

    async def _world_send(self, text: str) -> None:
        conn = self._world_conn
        if conn is not None:
            with contextlib.suppress(ConnectionClosed):
                await conn.send(text)


# ---------------------------------------------------------------------- in-process runs
class EngineOracle:
    """The automatic intruder's view of a gateway engine in the same process."""

    def __init__(self, engine: Engine) -> None:
        self._engine = engine

    @property
    def running(self) -> bool:
        """True once an execution started."""
        return self._engine.executor is not None

    @property
    def plan_id(self) -> int:
        """Number of the plan being executed."""
        ex = self._engine.executor
        assert ex is not None
        return ex.plan_id

    def paths(self) -> Sequence[Path]:
        """The current plan's paths."""
        ex = self._engine.executor
        assert ex is not None
        return ex.plan.paths

    def start_ms(self, robot: int, action: int) -> float:
        """The monitor's estimated start of an action."""
        ex = self._engine.executor
        assert ex is not None
        return ex.monitor.start_ms(robot, action)

    def completion_ms(self, robot: int, action: int) -> float:
        """The monitor's estimated completion of an action."""
        ex = self._engine.executor
        assert ex is not None
        return ex.monitor.completion_ms(robot, action)


def fleet_for(gateway: Gateway, robots: int, connect: Connect, *, seed: int = 0,
              intruder: bool = True, intruder_config: IntruderConfig | None = None,
              poll_at_ticks: bool = True, send_state: bool = False) -> SimFleet:
    """A fleet of robots ``0..robots-1`` for ``gateway`` in the same process (its clock, its
    world token, its executor as the automatic intruder's oracle if ``intruder``).

    With ``poll_at_ticks`` the intruder is stepped at the gateway's monitor ticks, after the
    robot events of that instant and before the tick (the discrete-event driver's order; driver
    2 needs it to match driver 3 exactly). Otherwise the fleet steps it on its own.
    """
    engine = gateway.engine
    fleet = SimFleet(connect, range(robots), clock=gateway.clock,
                     world_token=gateway.config.tokens.world[0],
                     oracle=EngineOracle(engine) if intruder else None, seed=seed,
                     intruder_config=intruder_config, send_state=send_state,
                     external_poll=poll_at_ticks)
    if poll_at_ticks:
        engine.before_tick.append(fleet.poll_world)
    return fleet


async def run_in_process(gateway: Gateway, problem: Problem, fleet: SimFleet,
                         before_start: Callable[[], Awaitable[None]] | None = None
                         ) -> RunSummary:
    """Load ``problem`` (with its plan) on ``gateway``, connect ``fleet``, wait for
    ``before_start`` (if given), start, and wait for the end of the execution. The fleet keeps
    running afterwards (the caller stops it)."""
    plan = problem.plan
    if plan is None:
        raise ValueError("the problem has no plan to execute")
    engine = gateway.engine
    replan_at: list[float] = []

    def on_status(status: str) -> None:
        if status == "replanning" and not replan_at:
            replan_at.append(engine.now_ms())

    engine.status_listeners.append(on_status)
    try:
        engine.load(problem)
        await fleet.start()
        await fleet.wait_connected()
        if before_start is not None:
            await before_start()
        error, detail = await gateway.command(Start(msg_id="run-start", seq=0))
        if error is not None:
            raise RuntimeError(f"the gateway refused to start: {detail}")
        soc, makespan = await gateway.wait_done()
    finally:
        engine.status_listeners.remove(on_status)
    ex = engine.executor
    assert ex is not None
    return RunSummary(soc_ms=soc, makespan_ms=makespan, plan_soc=plan.soc, replans=ex.replans,
                     replan_at_ms=replan_at[0] if replan_at else None,
                     solver_ms=engine.solvers.solver_ms, collisions=len(fleet.world.collisions))
