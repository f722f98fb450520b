"""The robot's link to the gateway: protocol v1 over websockets, around a :class:`RobotBody`.

Three tasks share one event loop:

* control: every ``control_period_ms`` it ticks the body (base feedback in, wheel command
  out), reports the runner's events (``started``, ``finished``; a bumper pause as ``blocked``
  / ``unblocked`` during a move and as ``state`` with activity ``blocked``, see
  :meth:`RobotClient._report`), and starts the next
  held action when the robot is idle, connected and not paused;
* camera: reads frames in a worker thread, measures tag fixes there and applies them;
* link: connects with the robot's token, says ``hello`` (pose, held and finished action ids,
  current activity), takes the ``welcome``, then acknowledges every action (a duplicate action
  id is acknowledged again but never executed twice; a duplicate of a finished action gets its
  ``finished`` again), honours cancel / pause / resume and sends a ``state`` snapshot every
  ``welcome.state_period_ms``. When the link is lost it reconnects with exponential backoff.

Actions are held in a queue (the gateway may release the next action before the current one
finishes) and executed strictly in the order of their index, each after the previous finished.

On link loss the running action is completed (its ``finished`` is remembered and reported in
the next ``hello``) and no further action starts until the gateway has welcomed the robot back.
"""

from __future__ import annotations

import asyncio
import logging
import uuid
from collections import deque
from typing import Any

from websockets.asyncio.client import ClientConnection, backoff, connect
from websockets.exceptions import ConnectionClosed, InvalidHandshake

from protocol import (
    MAX_MESSAGE_BYTES,
    Ack,
    Action,
    Activity,
    AnyMessage,
    Blocked,
    CancelAction,
    Cancelled,
    Error,
    Finished,
    Hello,
    Pause,
    ProtocolError,
    Resume,
    Started,
    State,
    Unblocked,
    Welcome,
    decode,
    encode,
)
from protocol import Pose as WirePose
from protocol.messages import RobotActivity
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

_REPORTS: dict[str, type[Started | Finished]] = {"started": Started, "finished": Finished}
_LINK_ERRORS = (OSError, TimeoutError, InvalidHandshake, ConnectionClosed, ProtocolError)


class SessionRefused(Exception):
    """The gateway did not welcome the robot."""


def grid_action(msg: Action) -> GridAction:
    """The runner's view of a dispatched action."""
    return GridAction(msg.action_id, msg.src.cell, msg.dst.cell, msg.src.heading,
                      msg.dst.heading, msg.duration_ms)


class RobotClient:
    """One robot's connection to the gateway (see module doc). ``run`` until ``stop``."""

    def __init__(self, settings: RobotSettings, body: RobotBody,
                 frames: FrameSource | None = None) -> None:
        self.settings = settings
        self.body = body
        self.frames = frames
        self.floor = settings.floor()
        self.held: deque[GridAction] = deque()
        self.known: set[str] = set()
        self.finished: deque[str] = deque(maxlen=256)
        self.paused = False
        self.link: ClientConnection | None = None
        self.state_period_ms = 5000.0
        self.sessions = 0
        self.gateway_errors: deque[Error] = deque(maxlen=100)
        self._seq = 0
        self._send_lock = asyncio.Lock()
        self._stop = asyncio.Event()
        self._moved = False
        self._ssl = settings.ssl_context()

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

    def current(self) -> Activity | None:
        """The action the robot holds and what it does with it."""
        running = self.body.runner.action
        if running is not None:
            if self.body.runner.paused:
                return Activity(action_id=running.action_id, state="blocked")
            return Activity(action_id=running.action_id, state="running")
        if self.held:
            return Activity(action_id=self.held[0].action_id, state="received")
        return None

    def _battery(self) -> float | None:
        latest = self.body.base.latest
        if latest is None:
            return None
        frac = (latest.battery_v - BATTERY_EMPTY_V) / (BATTERY_FULL_V - BATTERY_EMPTY_V)
        return min(1.0, max(0.0, frac))

    # ---------------------------------------------------------------- sending

    async def _send(self, ws: ClientConnection, cls: type[AnyMessage], **fields: Any) -> bool:
        """Build (with this connection's next seq) and send one message; False if the link
        is gone."""
        async with self._send_lock:
            msg = cls(msg_id=uuid.uuid4().hex, seq=self._seq, **fields)
            self._seq += 1
            try:
                await ws.send(encode(msg))
            except ConnectionClosed:
                return False
        return True

    async def _report(self, event: RunnerEvent) -> None:
        """Tell the gateway about a runner event.

        A bumper pause (runner ``blocked`` / ``unblocked``) always happens after ``started``.
        During a move it is reported as protocol v2's stop on the way (``blocked``, then
        ``unblocked``: the executor's ``stopped``, so a replan can re-task the robot) and, as
        for a turn (which v2 does not stop), by an immediate ``state`` snapshot (activity
        ``blocked``, then ``running`` again).
        """
        if event.kind == "finished":
            self.finished.append(event.action_id)
        if event.kind == "started":
            self._moved = True
        if self.link is None:
            return
        if event.kind in _REPORTS:
            await self._send(self.link, _REPORTS[event.kind], action_id=event.action_id,
                             pose=self.wire_pose())
            return
        current = self.body.runner.action
        if current is not None and current.kind == "move":
            await self._send(self.link, Blocked if event.kind == "blocked" else Unblocked,
                             action_id=event.action_id, pose=self.wire_pose())
        await self._send_state(self.link)

    # ---------------------------------------------------------------- control

    async def _control_loop(self) -> None:
        loop = asyncio.get_running_loop()
        period = self.settings.control_period_ms / 1000.0
        deadline = loop.time()
        while True:
            now = monotonic_ms()
            for event in self.body.tick(now):
                await self._report(event)
            if not self.body.runner.busy and self.held and self.link is not None \
                    and not self.paused:
                action = self.held.popleft()
                log.info("starting %s (%s)", action.action_id, action.kind)
                self.body.start(action, now)
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
        headers = {"Authorization": f"Bearer {s.token.get_secret_value()}"}
        delays = None
        while True:
            welcomed = self.sessions
            try:
                async with connect(s.gateway_url, additional_headers=headers, proxy=None,
                                   open_timeout=s.ping_timeout_s * 2,
                                   ping_interval=s.ping_interval_s,
                                   ping_timeout=s.ping_timeout_s,
                                   max_size=MAX_MESSAGE_BYTES, ssl=self._ssl) as ws:
                    await self._session(ws)
                log.warning("gateway closed the link")
            except (*_LINK_ERRORS, SessionRefused) as exc:
                log.warning("link to %s lost or refused: %s", s.gateway_url, exc)
            self.link = None
            if self.sessions != welcomed or delays is None:
                delays = backoff(s.reconnect_min_s, s.reconnect_min_s, s.reconnect_max_s)
            await asyncio.sleep(next(delays))

    async def _session(self, ws: ClientConnection) -> None:
        """One connection: hello, welcome, then messages until the link closes."""
        self._seq = 0
        held = [a.action_id for a in self.held]
        running = self.body.runner.action
        await self._send(ws, Hello, robot_id=self.settings.robot_id, pose=self.wire_pose(),
                         acked=([running.action_id] if running else []) + held,
                         finished=list(self.finished), current=self.current())
        first = decode(await asyncio.wait_for(ws.recv(), self.settings.ping_timeout_s * 2))
        if not isinstance(first, Welcome):
            detail = f" {first.code}: {first.detail}" if isinstance(first, Error) else ""
            raise SessionRefused(f"expected welcome, got {first.type}{detail}")
        self.sessions += 1
        self._welcome(first)
        for action in first.resend:
            await self._on_action(ws, action)
        self.link = ws
        state_task = asyncio.create_task(self._state_loop(ws))
        try:
            async for raw in ws:
                try:
                    msg = decode(raw)
                except ProtocolError as exc:
                    log.warning("undecodable message from the gateway: %s", exc)
                    continue
                await self._on_message(ws, msg)
        finally:
            self.link = None
            state_task.cancel()

    def _welcome(self, msg: Welcome) -> None:
        self.state_period_ms = msg.state_period_ms
        self.paused = msg.paused
        loc: Localiser = self.body.localiser
        if msg.start is not None and loc.last_fix is None and not self._moved:
            x, y = self.floor.centre(msg.start.cell)
            theta = HEADING_ANGLE[msg.start.heading] if msg.start.heading else loc.pose.theta
            loc.pose = Pose(x, y, theta)
        log.info("welcomed (plan %s, %d to resend)", msg.plan, len(msg.resend))

    async def _send_state(self, ws: ClientConnection) -> None:
        await self._send(ws, State, robot_id=self.settings.robot_id, pose=self.wire_pose(),
                         activity=self._activity(), current=self.current(),
                         battery=self._battery())

    async def _state_loop(self, ws: ClientConnection) -> None:
        while True:
            await self._send_state(ws)
            await asyncio.sleep(self.state_period_ms / 1000.0)

    def _activity(self) -> RobotActivity:
        cur = self.current()
        if cur is not None:
            return cur.state
        return "paused" if self.paused else "idle"

    async def _on_message(self, ws: ClientConnection, msg: AnyMessage) -> None:
        if isinstance(msg, Action):
            await self._on_action(ws, msg)
        elif isinstance(msg, CancelAction):
            await self._on_cancel(ws, msg.action_id)
        elif isinstance(msg, Pause):
            self.paused = True
        elif isinstance(msg, Resume):
            self.paused = False
        elif isinstance(msg, Error):
            self.gateway_errors.append(msg)
            log.warning("gateway error %s (ref %s): %s", msg.code, msg.ref, msg.detail)
        else:
            log.warning("ignoring unexpected %s message", msg.type)

    async def _on_action(self, ws: ClientConnection, msg: Action) -> None:
        if msg.action_id in self.known:
            await self._send(ws, Ack, action_id=msg.action_id)
            if msg.action_id in self.finished:
                await self._send(ws, Finished, action_id=msg.action_id, pose=self.wire_pose())
            return
        action = grid_action(msg)
        try:
            action.validate()
        except ValueError as exc:
            log.error("refusing action %s: %s", msg.action_id, exc)
            return
        self.known.add(msg.action_id)
        self.held.append(action)
        await self._send(ws, Ack, action_id=msg.action_id)

    async def _on_cancel(self, ws: ClientConnection, action_id: str) -> None:
        """Drop a held (not started) action and every action queued behind it (they cannot
        run without it; the gateway cancels all of a robot's queued actions at once) and
        confirm each. A dropped action may be dispatched again (an abandoned replan)."""
        ids = [a.action_id for a in self.held]
        if action_id not in ids:
            return  # running (it completes and reports finished), finished or dropped already
        dropped = ids[ids.index(action_id):]
        for _ in dropped:
            self.held.pop()
        for aid in dropped:
            self.known.discard(aid)
            await self._send(ws, Cancelled, action_id=aid, pose=self.wire_pose())


def build_client(settings: RobotSettings, base: KobukiSerial,
                 frames: FrameSource | None) -> RobotClient:
    """Assemble localiser, runner, body and client from the settings."""
    floor = settings.floor()
    x, y = floor.centre((settings.start_x, settings.start_y))
    localiser = Localiser(TagLocator(floor, settings.camera()),
                          Pose(x, y, HEADING_ANGLE[settings.start_heading]),
                          tag_gain=settings.tag_gain)
    runner = ActionRunner(floor, settings.runner_params())
    return RobotClient(settings, RobotBody(base, localiser, runner), frames)
