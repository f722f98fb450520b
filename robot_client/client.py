"""The robot's link to the gateway: protocol v1 over websockets, around a :class:`RobotBody`.

Three tasks share one event loop:

* control: every ``control_period_ms`` it ticks the body (base feedback in, wheel command
  out), reports the runner's events (``started``, ``finished``; a bumper pause as ``blocked``
  / ``unblocked`` during a move and as ``state`` with activity ``blocked``, see
  :meth:`RobotClient._report`; a replan's ``cancel`` of such a stopped move makes the robot
  drive back to the move's source, then confirm ``cancelled``), and starts the next
  held action when the robot is idle, connected and not paused;
* camera: reads frames in a worker thread, measures tag fixes there and applies them;
* link: connects with the robot's token, runs the protocol session and sends a ``state``
  snapshot every ``welcome.state_period_ms``. When the link is lost it reconnects with
  exponential backoff.

The protocol's rules (hello, acknowledgements, duplicates, the action queue, cancel, pause,
what a reconnect reports) are the sans-I/O :class:`protocol.robot_session.RobotSession`, shared
with the simulated robots; this module only moves its messages and its body. Time comes from an
injectable :class:`RobotClock` (monotonic by default; tests run the client in virtual time).
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import uuid
from collections.abc import Awaitable, Callable
from typing import Protocol

from websockets.asyncio.client import backoff, connect
from websockets.exceptions import ConnectionClosed, ConnectionClosedOK, InvalidHandshake

from protocol import MAX_MESSAGE_BYTES, Action, Error, ProtocolError, Welcome, decode, encode
from protocol import Pose as WirePose
from protocol.robot_session import (
    Abort,
    GatewayError,
    Refused,
    RobotSession,
    Send,
    Welcomed,
)
from robot_client.apriltag_localiser import Localiser, TagLocator
from robot_client.body import RobotBody
from robot_client.config import RobotSettings
from robot_client.floor import HEADING_ANGLE, nearest_heading
from robot_client.frames import FrameSource, monotonic_ms
from robot_client.kobuki import KobukiSerial
from robot_client.odometry import Pose
from robot_client.runner import ActionRunner, GridAction, RunnerEvent

log = logging.getLogger("fleetgate.robot")

BATTERY_EMPTY_V, BATTERY_FULL_V = 13.2, 16.5
"""Kobuki pack voltages taken as 0 % and 100 % for the rough ``state.battery`` figure."""

_LINK_ERRORS = (OSError, TimeoutError, InvalidHandshake, ConnectionClosed, ProtocolError)


class SessionRefused(Exception):
    """The gateway did not welcome the robot."""


class Connection(Protocol):
    """What the client needs of a link: a websockets client connection, or an in-memory one."""

    async def send(self, message: str) -> None:
        """Send one text frame."""
        ...

    async def recv(self) -> str | bytes:
        """The next frame; raises ``websockets.ConnectionClosed`` once closed."""
        ...

    async def close(self, code: int = 1000, reason: str = "") -> None:
        """Close the connection."""
        ...


Connector = Callable[[RobotSettings], Awaitable[Connection]]
"""Opens an authenticated connection to the gateway (default: :func:`websocket_connect`)."""


async def websocket_connect(s: RobotSettings) -> Connection:
    """A websocket to ``s.gateway_url`` with the robot's bearer token and keepalive pings."""
    headers = {"Authorization": f"Bearer {s.token.get_secret_value()}"}
    return await connect(s.gateway_url, additional_headers=headers, proxy=None,
                         open_timeout=s.ping_timeout_s * 2, ping_interval=s.ping_interval_s,
                         ping_timeout=s.ping_timeout_s, max_size=MAX_MESSAGE_BYTES,
                         ssl=s.ssl_context())


class RobotClock(Protocol):
    """The robot's time source (the body's control ticks and camera frames use it)."""

    def now_ms(self) -> float:
        """Milliseconds on a monotonic scale."""
        ...


class MonotonicClock:
    """Real time: :func:`robot_client.frames.monotonic_ms`."""

    def now_ms(self) -> float:
        """Monotonic milliseconds."""
        return monotonic_ms()


def grid_action(msg: Action) -> GridAction:
    """The runner's view of a dispatched action."""
    return GridAction(msg.action_id, msg.src.cell, msg.dst.cell, msg.src.heading,
                      msg.dst.heading, msg.duration_ms)


def _check_action(msg: Action) -> None:
    grid_action(msg).validate()


class RobotClient:
    """One robot's connection to the gateway (see module doc). ``run`` until ``stop``.

    ``clock`` gives the time (monotonic by default); all waiting is on the event loop, so on
    a virtual-time loop with a clock that reads it the whole client runs in virtual time.
    ``connect`` opens the link (a websocket by default).
    """

    def __init__(self, settings: RobotSettings, body: RobotBody,
                 frames: FrameSource | None = None, *, clock: RobotClock | None = None,
                 connect: Connector = websocket_connect) -> None:
        self.settings = settings
        self.body = body
        self.frames = frames
        self.clock: RobotClock = clock if clock is not None else MonotonicClock()
        self.floor = settings.floor()
        self.session = RobotSession(settings.robot_id, msg_prefix=f"{uuid.uuid4().hex[:12]}-",
                                    check=_check_action)
        self.link: Connection | None = None
        self.gateway_errors: list[Error] = []
        self._connect = connect
        self._send_lock = asyncio.Lock()
        self._stop = asyncio.Event()
        self._moved = False

    # ---------------------------------------------------------------- what it holds
    @property
    def held(self) -> list[GridAction]:
        """Actions received and not started, in the order they will run."""
        return [grid_action(a) for a in self.session.queue]

    @property
    def known(self) -> set[str]:
        """Ids of the actions held, running or recently finished."""
        ids = {a.action_id for a in self.session.queue} | set(self.session.finished)
        return ids | ({self.session.current} if self.session.current else set())

    @property
    def finished(self) -> list[str]:
        """The recently finished action ids, oldest first."""
        return self.session.finished

    @property
    def sessions(self) -> int:
        """How many times the gateway welcomed the robot."""
        return self.session.welcomes

    # ---------------------------------------------------------------- lifecycle

    def stop(self) -> None:
        """Ask :meth:`run` to return (the base is stopped)."""
        self._stop.set()

    async def run(self) -> None:
        """Run the control, camera and link tasks until :meth:`stop` (or one of them fails)."""
        tasks = [asyncio.create_task(self._control_loop(), name="control"),
                 asyncio.create_task(self._link_loop(), name="link")]
        if self.frames is not None:
            tasks.append(asyncio.create_task(self._camera_loop(), name="camera"))
        stopper = asyncio.create_task(self._stop.wait())
        try:
            await asyncio.wait([*tasks, stopper], return_when=asyncio.FIRST_COMPLETED)
        finally:
            for t in [*tasks, stopper]:
                t.cancel()
            await asyncio.gather(*tasks, stopper, return_exceptions=True)
            self.body.stop()
        for t in tasks:
            if not t.cancelled() and t.exception() is not None:
                raise t.exception()  # type: ignore[misc]

    # ---------------------------------------------------------------- what the robot is

    def wire_pose(self) -> WirePose:
        """The pose estimate as the protocol's cell + heading (clamped onto the grid)."""
        p = self.body.pose
        col, row = self.floor.cell_at(p.x, p.y)
        col = min(max(col, 0), self.floor.width - 1)
        row = min(max(row, 0), self.floor.height - 1)
        return WirePose(cell=(col, row), heading=nearest_heading(p.theta))

    def _battery(self) -> float | None:
        latest = self.body.base.latest
        if latest is None:
            return None
        frac = (latest.battery_v - BATTERY_EMPTY_V) / (BATTERY_FULL_V - BATTERY_EMPTY_V)
        return min(1.0, max(0.0, frac))

    # ---------------------------------------------------------------- session effects

    async def _flush(self) -> None:
        """Carry out what the session asks, in order: send its messages on the link."""
        async with self._send_lock:
            for effect in self.session.drain():
                if isinstance(effect, Send):
                    if self.link is not None:
                        with contextlib.suppress(ConnectionClosed):
                            await self.link.send(encode(effect.message))
                elif isinstance(effect, Welcomed):
                    self._welcome(effect.welcome)
                elif isinstance(effect, GatewayError):
                    err = effect.error
                    self.gateway_errors.append(err)
                    del self.gateway_errors[:-100]
                    log.warning("gateway error %s (ref %s): %s", err.code, err.ref, err.detail)
                elif isinstance(effect, Refused):
                    log.error("refused action %s: %s", effect.action.action_id, effect.reason)
                elif isinstance(effect, Abort):  # a move stopped on the way by the bumper
                    log.info("cancelled on the way: %s goes back", effect.action_id)
                    self.body.runner.abort(self.clock.now_ms(), self.body.pose)

    async def _report(self, event: RunnerEvent) -> None:
        """Tell the gateway about a runner event.

        A bumper pause (runner ``blocked`` / ``unblocked``) always happens after ``started``.
        During a move it is reported as protocol v2's stop on the way (``blocked``, then
        ``unblocked``: the executor's ``stopped``, so a replan can re-task the robot) and, as
        for a turn (which v2 does not stop), by an immediate ``state`` snapshot (activity
        ``blocked``, then ``running`` again).
        """
        if event.kind == "started":
            self._moved = True
        if event.kind in ("started", "finished"):
            self.session.report(event.kind, event.action_id, self.wire_pose())
        elif event.kind == "cancelled":  # back on the source of a move a cancel aborted
            self.session.aborted(event.action_id, self.wire_pose())
        else:
            current = self.body.runner.action
            if current is not None and current.kind == "move":
                self.session.report(event.kind, event.action_id, self.wire_pose())
            self.session.state(self.wire_pose(), battery=self._battery(),
                               held_up=event.kind == "blocked")
        await self._flush()

    # ---------------------------------------------------------------- control

    async def _control_loop(self) -> None:
        loop = asyncio.get_running_loop()
        period = self.settings.control_period_ms / 1000.0
        deadline = loop.time()
        while True:
            now = self.clock.now_ms()
            for event in self.body.tick(now):
                await self._report(event)
            if not self.body.runner.busy:
                action = self.session.take()
                if action is not None:
                    grid = grid_action(action)
                    log.info("starting %s (%s)", grid.action_id, grid.kind)
                    try:
                        self.body.start(grid, now)
                    except ValueError as exc:  # e.g. a move whose start heading it lacks
                        self.session.refuse_current("pose_mismatch", str(exc),
                                                    self.wire_pose())
                        await self._flush()
            deadline += period
            await asyncio.sleep(max(0.0, deadline - loop.time()))

    async def _camera_loop(self) -> None:
        assert self.frames is not None
        locator = self.body.localiser.locator
        period = self.settings.camera_period_ms / 1000.0
        while True:
            frame = await asyncio.to_thread(self.frames.read)
            if frame is not None:
                fix = await asyncio.to_thread(locator.locate, frame.image)
                if fix is not None:
                    # replay on the fix the motion made since the frame was captured
                    self.body.localiser.apply(fix, seen_at=self.body.pose_at(frame.t_ms))
            await asyncio.sleep(period)

    # ---------------------------------------------------------------- link

    async def _link_loop(self) -> None:
        s = self.settings
        delays = None
        while True:
            welcomed = self.sessions
            try:
                conn = await self._connect(s)
                try:
                    await self._session(conn)
                finally:
                    await conn.close()
                log.warning("gateway closed the link")
            except (*_LINK_ERRORS, SessionRefused) as exc:
                log.warning("link to %s lost or refused: %s", s.gateway_url, exc)
            if self.sessions != welcomed or delays is None:
                delays = backoff(s.reconnect_min_s, s.reconnect_min_s, s.reconnect_max_s)
            await asyncio.sleep(next(delays))

    async def _session(self, conn: Connection) -> None:
        """One connection: hello, welcome, then messages until the link closes."""
        self.link = conn
        state_task: asyncio.Task[None] | None = None
        try:
            self.session.connected(self.wire_pose())
            await self._flush()
            first = decode(await asyncio.wait_for(conn.recv(), self.settings.ping_timeout_s * 2))
            if isinstance(first, Error):  # a gateway that predates v3: hello again in v2
                spoke = self.session.version
                self.session.receive(first)
                await self._flush()
                if self.session.version != spoke:
                    first = decode(await asyncio.wait_for(conn.recv(),
                                                          self.settings.ping_timeout_s * 2))
            if not isinstance(first, Welcome):
                detail = f" {first.code}: {first.detail}" if isinstance(first, Error) else ""
                raise SessionRefused(f"expected welcome, got {first.type}{detail}")
            self.session.receive(first)
            await self._flush()
            state_task = asyncio.create_task(self._state_loop())
            while True:
                try:
                    raw = await conn.recv()
                except ConnectionClosedOK:
                    return
                try:
                    msg = decode(raw)
                except ProtocolError as exc:
                    log.warning("undecodable message from the gateway: %s", exc)
                    continue
                self.session.receive(msg)
                await self._flush()
        finally:
            self.link = None
            self.session.disconnected()
            if state_task is not None:
                state_task.cancel()

    def _welcome(self, msg: Welcome) -> None:
        loc: Localiser = self.body.localiser
        if msg.start is not None and loc.last_fix is None and not self._moved:
            x, y = self.floor.centre(msg.start.cell)
            theta = HEADING_ANGLE[msg.start.heading] if msg.start.heading else loc.pose.theta
            loc.pose = Pose(x, y, theta)
        log.info("welcomed (plan %s, %d to resend)", msg.plan, len(msg.resend))

    async def _state_loop(self) -> None:
        while True:
            self.session.state(self.wire_pose(), battery=self._battery(),
                               held_up=self.body.runner.paused)
            await self._flush()
            await asyncio.sleep(self.session.state_period_ms / 1000.0)


def build_client(settings: RobotSettings, base: KobukiSerial, frames: FrameSource | None, *,
                 clock: RobotClock | None = None,
                 connect: Connector = websocket_connect) -> RobotClient:
    """Assemble localiser, runner, body and client from the settings (``clock`` and
    ``connect`` as in :class:`RobotClient`)."""
    floor = settings.floor()
    x, y = floor.centre((settings.start_x, settings.start_y))
    localiser = Localiser(TagLocator(floor, settings.camera()),
                          Pose(x, y, HEADING_ANGLE[settings.start_heading]),
                          tag_gain=settings.tag_gain)
    runner = ActionRunner(floor, settings.runner_params())
    return RobotClient(settings, RobotBody(base, localiser, runner), frames, clock=clock,
                       connect=connect)
