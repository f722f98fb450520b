"""The checklist a robot goes through: the checker plays the gateway (it listens, the robot
connects) and moves the robot back and forth on the cells ``(0..4, 0)`` of its floor."""

from __future__ import annotations

import asyncio
import contextlib
import itertools
import os
import shlex
import signal
import tempfile
from collections import defaultdict
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any
from urllib.parse import parse_qs, urlsplit

from websockets.asyncio.server import Server, ServerConnection, serve
from websockets.http11 import Request, Response

from conformance.checklist import Checklist, add_envelope_checks
from conformance.report import CheckFailed, CheckResult, UsageProblem
from conformance.wire import Breaches, Conn
from protocol import (
    PROTOCOL_VERSION,
    Ack,
    Action,
    ActionRefused,
    AnyMessage,
    Blocked,
    CancelAction,
    Cancelled,
    Error,
    ErrorCode,
    Finished,
    Hello,
    Pause,
    Pose,
    Resume,
    Started,
    State,
    Unblocked,
    Welcome,
    parse_action_id,
)
from protocol.messages import FOLDED_ACK

Cell = tuple[int, int]

STATE_PERIOD_MS = 300.0
"""The ``state`` period the checker asks for in its welcomes."""
DURATION_MS = 200.0
"""The expected duration of the checker's actions."""
ACT_S = 15.0
"""How long a robot may take to start or finish an action."""
QUIET_S = 0.4
LONG_MS = 1500.0
"""A wait that outlasts the robot's reconnection."""
"""How long the checker waits to be sure a robot does not do something."""

_REPORTS = (Started, Finished, Blocked, Unblocked, Cancelled, ActionRefused)


@dataclass
class RobotOptions:
    """What the user told the checker about the robot."""

    robot_id: int
    token: str
    listen: str | None = None
    command: str | None = None
    connect_timeout_s: float = 20.0


@dataclass
class FakeGateway:
    """The checker's gateway: accepts the robot's connections and dispatches its actions."""

    options: RobotOptions
    breaches: Breaches = field(default_factory=Breaches)
    conn: Conn | None = None
    hellos: list[Hello] = field(default_factory=list)
    refused: list[str] = field(default_factory=list)
    accepted_tokens: int = 0
    cell: Cell = (0, 0)
    direction: int = 1
    plan: int = 1
    index: int = 0
    dispatched: dict[str, dict[str, Any]] = field(default_factory=dict)
    reports: dict[str, list[str]] = field(default_factory=lambda: defaultdict(list))
    acks: set[str] = field(default_factory=set)
    sent: set[str] = field(default_factory=set)
    cancels: set[str] = field(default_factory=set)
    foreign: list[str] = field(default_factory=list)
    states: list[tuple[float, State]] = field(default_factory=list)
    _links: asyncio.Queue[Conn] = field(default_factory=asyncio.Queue)
    _server: Server | None = None
    _proc: asyncio.subprocess.Process | None = None
    _log: Any = None
    url: str = ""
    links: int = 0
    carried: tuple[str, str, Hello] | None = None

    @property
    def robot_id(self) -> int:
        """The robot's id."""
        return self.options.robot_id

    # ------------------------------------------------------------------ lifecycle
    async def start(self) -> None:
        """Listen, start the robot command if any, wait for the first connection and its
        hello, and welcome it. UsageProblem if the robot never comes."""
        opts = self.options
        parts = urlsplit(opts.listen or "ws://127.0.0.1:0/ws")
        try:
            self._server = await serve(self._handle, parts.hostname, parts.port or 0,
                                       process_request=self._authenticate, compression=None,
                                       ping_interval=None, max_size=4 * 1024 * 1024)
        except OSError as exc:
            raise UsageProblem(f"cannot listen on {parts.netloc}: {exc.strerror}") from None
        port = self._server.sockets[0].getsockname()[1]
        self.url = f"ws://{parts.hostname}:{port}{parts.path or '/'}"
        if opts.command is not None:
            cmd = (opts.command.replace("{url}", shlex.quote(self.url))
                   .replace("{token}", shlex.quote(opts.token))
                   .replace("{robot_id}", str(opts.robot_id)))
            self._log = tempfile.TemporaryFile()  # noqa: SIM115 (closed in stop())
            self._proc = await asyncio.create_subprocess_shell(
                cmd, stdin=asyncio.subprocess.DEVNULL, stdout=self._log, stderr=self._log,
                start_new_session=True)
        await self._first_link()

    async def _first_link(self) -> None:
        waiters: list[asyncio.Future[Any]] = [asyncio.ensure_future(self._links.get())]
        if self._proc is not None:
            waiters.append(asyncio.ensure_future(self._proc.wait()))
        done, pending = await asyncio.wait(waiters, timeout=self.options.connect_timeout_s,
                                           return_when=asyncio.FIRST_COMPLETED)
        for w in pending:
            w.cancel()
        if waiters[0] not in done:
            if self._proc is not None and self._proc.returncode is not None:
                raise UsageProblem(f"the robot command exited with code {self._proc.returncode}"
                                   f" before connecting{self._tail()}")
            how = "" if self.refused else " (no connection attempt)"
            raise UsageProblem(f"the robot did not connect to {self.url} within "
                               f"{self.options.connect_timeout_s:g} s{how}"
                               f"{'; refused: ' + self.refused[0] if self.refused else ''}")
        self.conn = waiters[0].result()
        self._watch(self.conn)

    def _tail(self) -> str:
        if self._log is None:
            return ""
        self._log.seek(0)
        lines = [ln for ln in self._log.read().decode(errors="replace").splitlines() if ln]
        return f": {lines[-1][:200]}" if lines else ""

    async def stop(self) -> None:
        """Stop the robot command (its process group), close everything."""
        if self._proc is not None and self._proc.returncode is None:
            with contextlib.suppress(ProcessLookupError):
                os.killpg(self._proc.pid, signal.SIGTERM)
            try:
                await asyncio.wait_for(self._proc.wait(), 5.0)
            except TimeoutError:
                with contextlib.suppress(ProcessLookupError):
                    os.killpg(self._proc.pid, signal.SIGKILL)
                await self._proc.wait()
        if self.conn is not None:
            await self.conn.close()
        if self._server is not None:
            self._server.close()
            await self._server.wait_closed()
        if self._log is not None:
            self._log.close()

    def _authenticate(self, connection: ServerConnection, request: Request
                      ) -> Response | None:
        token = None
        scheme, _, value = request.headers.get("Authorization", "").partition(" ")
        if scheme.lower() == "bearer" and value.strip():
            token = value.strip()
        else:
            values = parse_qs(urlsplit(request.path).query).get("token")
            token = values[0] if values else None
        if token == self.options.token:
            self.accepted_tokens += 1
            return None
        self.refused.append("no token" if token is None else "a wrong token")
        return connection.respond(401 if token is None else 403, "wrong token\n")

    async def _handle(self, ws: ServerConnection) -> None:
        self.links += 1
        conn = Conn(ws, self.breaches, f"link {self.links}")
        self._links.put_nowait(conn)
        await ws.wait_closed()

    def _watch(self, conn: Conn) -> None:
        """Record every report, ack and state of the robot on ``conn``."""
        loop = asyncio.get_running_loop()

        def note(msg: AnyMessage) -> None:
            if isinstance(msg, (*_REPORTS, Ack)):
                r = parse_action_id(msg.action_id)[1]
                if r != self.robot_id or (msg.action_id not in self.dispatched and not (
                        isinstance(msg, Cancelled) and msg.action_id in self.cancels)):
                    self.foreign.append(f"{msg.type} of {msg.action_id}")
                if isinstance(msg, Ack):
                    self.acks.add(msg.action_id)
                else:
                    self.reports[msg.action_id].append(msg.type)
            elif isinstance(msg, State):
                self.states.append((loop.time(), msg))
            elif isinstance(msg, Hello):
                self.hellos.append(msg)

        conn.on_message = note
        for msg in conn.received:
            note(msg)

    # ------------------------------------------------------------------ the gateway's side
    def c(self) -> Conn:
        """The robot's current connection."""
        if self.conn is None:
            raise CheckFailed("the robot is not connected")
        return self.conn

    async def hello(self) -> Hello:
        """The first message of the current connection, which must be ``hello``."""
        first = await self.c().expect("the robot's first message", lambda m: True, ACT_S)
        if not isinstance(first, Hello):
            raise CheckFailed(f"the robot's first message is {first.type}, not hello")
        self.c().version = first.v  # VER-2: the gateway answers in the robot's version
        return first

    async def welcome(self, resend: Sequence[str] = (), paused: bool = False,
                      drop: Sequence[str] = ()) -> None:
        """Send ``welcome`` (resending the named actions, dropping ``drop``)."""
        self.sent.update(resend)
        v = self.c().version or PROTOCOL_VERSION
        actions = [Action(msg_id=f"resend-{aid}", seq=0, v=v, **self.dispatched[aid])
                   for aid in resend]
        await self.c().send(Welcome, robot_id=self.robot_id, start=Pose(cell=(0, 0)),
                            plan=self.plan, resend=actions, drop=list(drop),
                            state_period_ms=STATE_PERIOD_MS, paused=paused)

    def moves_may_stop(self, aid: str) -> bool:
        """Whether ``aid`` is a move sent on a version 2 connection (BLOCK-2)."""
        fields = self.dispatched.get(aid)
        if fields is None or not self.hellos:
            return False
        return bool(fields["src"].cell != fields["dst"].cell and self.hellos[-1].v >= 2)

    def next_action(self, move: bool = False) -> str:
        """Plan the robot's next action, a wait or a move (back and forth on row 0); its
        action id."""
        x, y = self.cell
        if move and not 0 <= x + self.direction <= 4:
            self.direction = -self.direction
        dst = (x + self.direction, y) if move else (x, y)
        aid = f"{self.plan}.{self.robot_id}.{self.index}"
        self.dispatched[aid] = {"action_id": aid, "sequence": self.index,
                                "src": Pose(cell=(x, y)), "dst": Pose(cell=dst),
                                "duration_ms": DURATION_MS}
        self.index += 1
        self.cell = dst
        return aid

    def folds_acks(self) -> bool:
        """Whether the robot's current connection is of protocol v3 or later, whose robots
        send no ``ack`` (their first report about an action acknowledges it)."""
        return (self.c().version or PROTOCOL_VERSION) >= FOLDED_ACK

    async def acked(self, aid: str) -> None:
        """The robot's next ``ack`` of ``aid`` (v1, v2). A v3 robot sends none for an action
        it holds: nothing to wait for (it reads its link in order, so it took ``aid`` before
        anything the checker sends later)."""
        if not self.folds_acks():
            await self.c().expect_type(Ack, ACT_S, lambda m: m.action_id == aid,
                                       what=f"ack of {aid}")

    async def answered(self, aid: str) -> None:
        """The robot acknowledges ``aid``: an ``ack`` (v1, v2), or (v3) a first report about it
        and no ``ack`` (the report stays unclaimed for the checks that wait for it)."""
        if not self.folds_acks():
            await self.acked(aid)
            return
        loop = asyncio.get_running_loop()
        end = loop.time() + ACT_S
        while not self.reports[aid]:
            if loop.time() > end:
                raise CheckFailed(f"no report about {aid} within {ACT_S:g} s (protocol v3 "
                                  "acknowledges an action with its first report)")
            await asyncio.sleep(0.02)
        if aid in self.acks:
            raise CheckFailed(f"a version 3 robot sent an ack of {aid} (ACK-1: none in v3)")

    async def send(self, aid: str) -> None:
        """Send (or send again) action ``aid``."""
        self.sent.add(aid)
        await self.c().send(Action, **self.dispatched[aid])

    async def dispatch(self, move: bool = False) -> str:
        """Plan and send the next action (a wait unless ``move``); its id."""
        aid = self.next_action(move)
        await self.send(aid)
        return aid

    async def cancel(self, aid: str) -> None:
        """Send ``cancel`` of ``aid``."""
        self.cancels.add(aid)
        await self.c().send(CancelAction, action_id=aid)

    def cancelled_from(self, aid: str) -> None:
        """``aid`` and what was planned after it will not run: the robot stays on its source;
        the next actions belong to a new plan (as after a replan)."""
        src = self.dispatched[aid]["src"].cell
        self.cell = (int(src[0]), int(src[1]))
        self.plan, self.index = self.plan + 1, 0

    async def report(self, kind: type[AnyMessage], aid: str, timeout: float = ACT_S
                     ) -> AnyMessage:
        """The robot's next ``kind`` report about ``aid``."""
        name = kind.__name__.lower()
        return await self.c().expect(
            f"{name} of {aid}",
            lambda m: isinstance(m, kind) and getattr(m, "action_id", None) == aid, timeout)

    async def executes(self, aid: str) -> None:
        """The robot reports ``started`` and ``finished`` of ``aid``."""
        await self.report(Started, aid)
        await self.report(Finished, aid)

    async def no_start(self, aid: str, seconds: float = QUIET_S) -> None:
        """CheckFailed if the robot starts ``aid`` within ``seconds``."""
        await self.c().quiet(f"started of {aid}",
                             lambda m: isinstance(m, Started) and m.action_id == aid, seconds)

    async def drop_link(self) -> Hello:
        """Close the robot's connection (as a lost link) and take its next one; its hello
        (not welcomed yet)."""
        old = self.c()
        await old.close(1011)
        try:
            conn = await asyncio.wait_for(self._links.get(), ACT_S)
        except TimeoutError:
            self.conn = None
            raise CheckFailed(f"the robot did not reconnect within {ACT_S:g} s") from None
        self.conn = conn
        self._watch(conn)
        return await self.hello()

    async def idle(self) -> None:
        """Let pending reports and acks of the last step arrive and drop them."""
        await asyncio.sleep(0.05)
        self.c().take((Ack, State))


ROBOT_CHECKS: Checklist[FakeGateway] = Checklist(time_limit_s=45.0)
check = ROBOT_CHECKS.check


@check("robot-presents-its-token", "AUTH-1")
async def _token(g: FakeGateway) -> None:
    """The robot presents its token in the handshake (bearer header or ?token=)."""
    if g.refused or not g.accepted_tokens:
        raise CheckFailed(f"handshakes refused: {', '.join(g.refused)}")


@check("first-message-is-hello", "HS-1")
async def _hello(g: FakeGateway) -> None:
    """The robot's first message is ``hello``."""
    await g.hello()


@check("hello-names-the-robot", "AUTH-4")
async def _hello_id(g: FakeGateway) -> None:
    """``hello.robot_id`` is the robot's id."""
    if not g.hellos:
        raise CheckFailed("no hello")
    if g.hellos[0].robot_id != g.robot_id:
        raise CheckFailed(f"hello.robot_id is {g.hellos[0].robot_id}, expected {g.robot_id}")
    await g.welcome()


@check("acks-an-action", "ACK-1")
async def _ack(g: FakeGateway) -> None:
    """The robot acknowledges an action: with ``ack`` in version 1 and 2, with its first
    report and no ``ack`` in version 3."""
    aid = await g.dispatch(move=True)
    await g.answered(aid)


@check("executes-an-action", "REPORT-1")
async def _executes(g: FakeGateway) -> None:
    """The robot reports ``started`` then ``finished`` of an action."""
    aid = f"{g.plan}.{g.robot_id}.{g.index - 1}"
    await g.executes(aid)


@check("finished-pose-is-dst", "REPORT-2", required=False)
async def _pose(g: FakeGateway) -> None:
    """``finished`` carries the pose, on the action's target cell."""
    aid = await g.dispatch(move=True)
    await g.report(Started, aid)
    fin = await g.report(Finished, aid)
    assert isinstance(fin, Finished)
    want = g.dispatched[aid]["dst"].cell
    if fin.pose is None or tuple(fin.pose.cell) != tuple(want):
        raise CheckFailed(f"finished.pose is {fin.pose}, expected cell {want}")


@check("executes-queue-in-order", "DISPATCH-4")
async def _queue(g: FakeGateway) -> None:
    """With two actions queued the second starts only after the first finished."""
    first, second = await g.dispatch(move=True), await g.dispatch(move=True)
    await g.executes(first)
    await g.executes(second)
    order = [(m.type, m.action_id) for m in g.c().received
             if isinstance(m, Started | Finished) and m.action_id in (first, second)]
    if order.index(("started", second)) < order.index(("finished", first)):
        raise CheckFailed(f"{second} started before {first} finished: {order}")


@check("duplicate-action-not-executed", "DUP-1")
async def _duplicate(g: FakeGateway) -> None:
    """An action sent twice (once while held, once after it finished) runs once."""
    await g.idle()
    aid = await g.dispatch()
    await g.send(aid)
    await g.executes(aid)
    await g.send(aid)
    await g.no_start(aid)
    starts = g.reports[aid].count("started")
    if starts != 1:
        raise CheckFailed(f"{aid} was started {starts} times")


@check("duplicate-acknowledged", "ACK-1", required=False)
async def _dup_ack(g: FakeGateway) -> None:
    """A duplicate action is acknowledged again (version 1 and 2; a version 3 robot sends no
    ``ack`` for it)."""
    aid = await g.dispatch()
    await g.executes(aid)
    if g.folds_acks():
        await g.send(aid)
        await g.c().quiet(f"ack of {aid}",
                          lambda m: isinstance(m, Ack) and m.action_id == aid, QUIET_S)
        return
    acks = sum(1 for m in g.c().received if isinstance(m, Ack) and m.action_id == aid)
    await g.send(aid)
    await g.acked(aid)
    await asyncio.sleep(0.05)
    again = sum(1 for m in g.c().received if isinstance(m, Ack) and m.action_id == aid)
    if again <= acks:
        raise CheckFailed(f"the duplicate of {aid} was not acknowledged")


@check("pause-stops-new-moves", "PAUSE-2")
async def _pause(g: FakeGateway) -> None:
    """A paused robot acknowledges but starts nothing until ``resume``."""
    await g.c().send(Pause, reason="conformance")
    aid = await g.dispatch()
    await g.acked(aid)
    await g.no_start(aid)
    await g.c().send(Resume)
    await g.executes(aid)


@check("cancel-of-a-queued-action", "CANCEL-2")
async def _cancel_queued(g: FakeGateway) -> None:
    """A held action that is cancelled is confirmed with ``cancelled`` and never runs."""
    await g.c().send(Pause, reason="conformance")
    aid = await g.dispatch()
    await g.acked(aid)
    await g.cancel(aid)
    await g.report(Cancelled, aid)
    g.cancelled_from(aid)
    await g.c().send(Resume)
    await g.no_start(aid)


@check("cancel-voids-the-queue-behind", "CANCEL-2")
async def _cancel_behind(g: FakeGateway) -> None:
    """Cancelling a queued action drops the actions queued behind it too, each confirmed
    once."""
    await g.c().send(Pause, reason="conformance")
    first, second = await g.dispatch(), await g.dispatch()
    for aid in (first, second):
        await g.acked(aid)
    await g.cancel(first)
    await g.cancel(second)
    await g.report(Cancelled, first)
    await g.report(Cancelled, second)
    g.cancelled_from(first)
    await g.c().send(Resume)
    await g.c().quiet("a start of a cancelled action",
                      lambda m: isinstance(m, Started) and m.action_id in (first, second),
                      QUIET_S)
    twice = [a for a in (first, second) if g.reports[a].count("cancelled") > 1]
    if twice:
        raise CheckFailed(f"cancelled reported more than once for {twice}")


@check("cancel-while-moving-finishes", "CANCEL-3")
async def _cancel_running(g: FakeGateway) -> None:
    """A cancel of the action the robot is moving on is answered by finishing it."""
    aid = await g.dispatch(move=True)
    await g.report(Started, aid)
    await g.cancel(aid)
    await g.report(Finished, aid)
    if "cancelled" in g.reports[aid]:
        raise CheckFailed(f"{aid} was reported cancelled after it started")


@check("stale-cancel-is-harmless", "CANCEL-4")
async def _stale_cancel(g: FakeGateway) -> None:
    """A cancel of an action the robot never got leaves it connected and working."""
    await g.cancel(f"{g.plan}.{g.robot_id}.999")
    aid = await g.dispatch()
    await g.executes(aid)


@check("refuses-a-mismatched-start", "REFUSE-1")
async def _refuse(g: FakeGateway) -> None:
    """An action that does not start where the robot stands is refused (``refused``, code
    ``pose_mismatch``), neither acknowledged nor run, and so is the next one of its plan
    (``queued_behind``); a new plan from where the robot stands runs."""
    await g.idle()
    x, y = g.cell
    elsewhere = Pose(cell=(x + 1 if x < 4 else x - 1, y))
    first, behind = (f"{g.plan}.{g.robot_id}.{i}" for i in (g.index, g.index + 1))
    for i, aid in enumerate((first, behind)):
        g.dispatched[aid] = {"action_id": aid, "sequence": g.index + i, "src": elsewhere,
                             "dst": elsewhere, "duration_ms": DURATION_MS}
        await g.send(aid)
    for aid, code in ((first, "pose_mismatch"), (behind, "queued_behind")):
        msg = await g.report(ActionRefused, aid)
        assert isinstance(msg, ActionRefused)
        if msg.code != code:
            raise CheckFailed(f"{aid} was refused with code {msg.code}, expected {code}")
    await g.no_start(first)
    if {first, behind} & g.acks:
        raise CheckFailed(f"refused actions were acknowledged: {sorted({first, behind})}")
    g.plan, g.index = g.plan + 1, 0
    await g.executes(await g.dispatch())


@check("error-is-not-fatal", "ERR-4")
async def _error(g: FakeGateway) -> None:
    """After an ``error`` from the gateway the robot stays connected and works."""
    await g.c().send(Error, code=ErrorCode.DUPLICATE, ref="nothing", detail="conformance")
    aid = await g.dispatch()
    await g.executes(aid)


@check("bad-messages-are-ignored", "ERR-4")
async def _garbage(g: FakeGateway) -> None:
    """Undecodable messages (not JSON, version 4, unknown type) do not stop the robot."""
    for raw in ("{not json", '{"v": 4, "type": "pause", "msg_id": "x", "seq": 0}',
                '{"v": 1, "type": "teleport", "msg_id": "y", "seq": 0}'):
        await g.c().send_raw(raw)
    aid = await g.dispatch()
    await g.executes(aid)


@check("robot-answers-ping", "WS-2")
async def _ping(g: FakeGateway) -> None:
    """The robot answers a websocket ping."""
    pong = await g.c().ws.ping()
    try:
        await asyncio.wait_for(pong, 5.0)
    except TimeoutError:
        raise CheckFailed("no pong within 5 s") from None


@check("state-every-period", "STATE-1")
async def _state(g: FakeGateway) -> None:
    """``state`` arrives every ``welcome.state_period_ms``."""
    loop = asyncio.get_running_loop()
    t0 = loop.time()
    window = 6 * STATE_PERIOD_MS / 1000.0
    await asyncio.sleep(window)
    times = [t for t, _ in g.states if t >= t0]
    if len(times) < 3:
        raise CheckFailed(f"{len(times)} state messages in {window:g} s with a period of "
                          f"{STATE_PERIOD_MS:g} ms")
    gaps = [b - a for a, b in itertools.pairwise(times)]
    if max(gaps) > 3 * STATE_PERIOD_MS / 1000.0:
        raise CheckFailed(f"a gap of {max(gaps) * 1000:.0f} ms between two state messages")


@check("state-names-the-robot", "STATE-2")
async def _state_id(g: FakeGateway) -> None:
    """Every ``state`` names the robot itself."""
    if not g.states:
        raise CheckFailed("no state message")
    bad = {s.robot_id for _, s in g.states if s.robot_id != g.robot_id}
    if bad:
        raise CheckFailed(f"state messages for robot(s) {sorted(bad)}")


@check("reconnects-with-hello", "LIVE-1")
async def _reconnect(g: FakeGateway) -> None:
    """After a lost link the robot reconnects and says ``hello`` again."""
    await g.idle()
    hello = await g.drop_link()
    if hello.robot_id != g.robot_id:
        raise CheckFailed(f"hello.robot_id is {hello.robot_id}")
    await g.welcome()
    aid = await g.dispatch()
    await g.executes(aid)


@check("hello-lists-held-actions", "HS-1")
async def _hello_held(g: FakeGateway) -> None:
    """A robot holding an action it has not started lists it in ``hello.acked``."""
    await g.c().send(Pause, reason="conformance")
    aid = await g.dispatch()
    await g.acked(aid)
    hello = await g.drop_link()
    if aid not in hello.acked:
        await g.welcome()
        raise CheckFailed(f"hello.acked is {hello.acked}, without the held {aid}")
    await g.welcome(paused=True)
    await g.no_start(aid)
    await g.c().send(Resume)
    await g.executes(aid)


@check("link-loss-mid-move", "LIVE-1")
async def _offline_finish(g: FakeGateway) -> None:
    """A move under way when the link drops is completed and its finish reported (in the
    next ``hello`` or after the welcome)."""
    aid = await g.dispatch(move=True)
    await g.report(Started, aid)
    hello = await g.drop_link()
    await g.welcome()
    if aid not in hello.finished:
        await g.report(Finished, aid)


@check("no-start-before-welcome", "LIVE-2")
async def _no_start_early(g: FakeGateway) -> None:
    """An action queued when the link dropped starts only after the robot is welcomed
    back (the one under way meanwhile completes)."""
    first = g.next_action()
    g.dispatched[first]["duration_ms"] = LONG_MS
    await g.send(first)
    second = await g.dispatch()
    await g.report(Started, first)
    loop = asyncio.get_running_loop()
    first_ends = loop.time() + LONG_MS / 1000.0
    hello = await g.drop_link()
    g.carried = (first, second, hello)
    try:  # past the end of the first action, when a robot that does not wait would start
        await g.no_start(second, max(first_ends - loop.time(), 0.0) + QUIET_S)
    finally:
        await g.welcome()


@check("finish-across-reconnect", "LIVE-1")
async def _finish_carried(g: FakeGateway) -> None:
    """The finish of the action that completed while the link was down (or before the
    welcome) is reported: in ``hello.finished`` or after it."""
    if g.carried is None:
        raise CheckFailed("not run: no-start-before-welcome did not get that far")
    first, second, hello = g.carried
    await g.executes(second)
    if first not in hello.finished and "finished" not in g.reports[first]:
        raise CheckFailed(f"{first} finished while the link was down, but neither the hello "
                          f"(finished={hello.finished}) nor a later finished reported it")


@check("resend-is-executed", "RESEND-2")
async def _resend(g: FakeGateway) -> None:
    """An action the robot does not hold, resent in ``welcome``, is executed."""
    await g.idle()
    aid = g.next_action()
    await g.drop_link()
    await g.welcome(resend=[aid])
    await g.executes(aid)


@check("resend-of-a-finished-action-dropped", "DUP-1")
async def _resend_done(g: FakeGateway) -> None:
    """An action it finished, resent in ``welcome``, is not executed again."""
    done = await g.dispatch()
    await g.executes(done)
    await g.drop_link()
    await g.welcome(resend=[done])
    await g.no_start(done)
    aid = await g.dispatch()
    await g.executes(aid)


@check("welcome-drop-never-starts", "RESEND-5")
async def _welcome_drop(g: FakeGateway) -> None:
    """A held action that the ``welcome`` lists in ``drop`` (the gateway does not stand behind
    it, e.g. of a run abandoned with ``--fresh``) never starts; a new plan's action does."""
    await g.c().send(Pause, reason="conformance")
    aid = await g.dispatch()
    await g.acked(aid)
    await g.drop_link()
    await g.welcome(drop=[aid])
    await g.no_start(aid)
    g.cancelled_from(aid)
    nxt = await g.dispatch()
    await g.executes(nxt)


@check("welcome-paused-is-honoured", "PAUSE-3")
async def _welcome_paused(g: FakeGateway) -> None:
    """A robot welcomed with ``paused`` starts nothing until ``resume``."""
    aid = g.next_action()
    await g.drop_link()
    await g.welcome(resend=[aid], paused=True)
    await g.no_start(aid)
    await g.c().send(Resume)
    await g.executes(aid)


# ---------------------------------------------------------------------- passive
@check("acks-every-action", "ACK-1")
async def _all_acked(g: FakeGateway) -> None:
    """Every action the robot received was acknowledged (or, if the link lost the ack, listed
    in its next `hello`), unless it refused it: with ``ack`` in version 1 and 2, by a report
    about it in version 3, whose robots send no ``ack`` at all."""
    await asyncio.sleep(0.1)
    held = {a for h in g.hellos for a in [*h.acked, *h.finished]}  # an ack the link lost
    refused = {a for a, kinds in g.reports.items() if "refused" in kinds}
    folded = bool(g.hellos) and g.hellos[-1].v >= FOLDED_ACK
    answered = {a for a, kinds in g.reports.items() if kinds} if folded else g.acks
    missing = sorted(g.sent - answered - held - refused)
    if missing:
        raise CheckFailed(f"never acknowledged: {missing[:5]}")
    if folded and g.acks:
        raise CheckFailed(f"a version 3 robot sent acks: of {sorted(g.acks)[:5]}")


@check("reports-only-its-actions", "AUTH-5")
async def _own(g: FakeGateway) -> None:
    """The robot reports only about actions dispatched to it."""
    if g.foreign:
        raise CheckFailed(f"reports about other actions: {g.foreign[:5]}")


@check("report-order", "REPORT-5")
async def _order(g: FakeGateway) -> None:
    """Per action: blocked/unblocked before started (and, in version 2, stops on the way of a
    move), started once, then finished (repeats allowed), or cancelled before started or
    after a stop, or refused before started."""
    bad = [f"{aid}: {' '.join(kinds)}" for aid, kinds in g.reports.items()
           if not _valid_reports(kinds, moving_stops=g.moves_may_stop(aid))]
    if bad:
        raise CheckFailed("; ".join(bad[:3]))


def _valid_reports(kinds: list[str], moving_stops: bool) -> bool:
    """Whether one action's reports follow REPORT-5 (``moving_stops``: v2 and a move)."""
    allowed = {  # phase -> the reports allowed in it, and the phase each leads to
        "waiting": {"blocked": "waiting", "unblocked": "waiting", "started": "moving",
                    "cancelled": "over", "refused": "over"},
        "moving": {"finished": "done"},
        "stopped": {"unblocked": "moving", "cancelled": "over"},
        "done": {"finished": "done"},
        "over": {},
    }
    if moving_stops:
        allowed["moving"] = {"finished": "done", "blocked": "stopped"}
    phase = "waiting"
    for kind in kinds:
        if kind not in allowed[phase]:
            return False
        phase = allowed[phase][kind]
    return True


add_envelope_checks(ROBOT_CHECKS, "robot")


async def run_robot_checks(options: RobotOptions, only: set[str] | None = None
                           ) -> list[CheckResult]:
    """Play the gateway for the robot through the checklist; UsageProblem if it never
    connects."""
    gateway = FakeGateway(options)
    try:
        await gateway.start()
        return await ROBOT_CHECKS.run(gateway, only=only)
    finally:
        await gateway.stop()
