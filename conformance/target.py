"""The gateway under test as the checker sees it: how to connect, the operator channel it uses
to load tiny plans, and the robots it plays (see docs/protocol.md, "Checking a gateway")."""

from __future__ import annotations

import asyncio
import contextlib
import ssl
from dataclasses import dataclass, field
from typing import Any
from urllib.parse import urlsplit, urlunsplit

from websockets.asyncio.client import connect
from websockets.exceptions import InvalidStatus

from conformance.report import CheckFailed, UsageProblem
from conformance.wire import Breaches, Conn
from protocol import (
    Ack,
    Action,
    AnyMessage,
    CancelAction,
    Cancelled,
    Error,
    Event,
    Finished,
    Hello,
    LoadInstance,
    LoadPlan,
    Ok,
    OperatorCommand,
    Pause,
    Resume,
    SetPolicy,
    Snapshot,
    Start,
    Started,
    Welcome,
    parse_action_id,
)
from protocol.messages import FOLDED_ACK, PROTOCOL_VERSION, ProtocolVersion

Cell = tuple[int, int]

OPEN_TIMEOUT_S = 5.0
BUSY = ("planning", "running", "paused", "replanning")
"""Gateway statuses of a fleet at work."""


def read_health(url: str, context: ssl.SSLContext | None) -> dict[str, Any] | None:
    """The JSON object ``url`` answers (any status), or None if there is none."""
    import json
    import urllib.error
    import urllib.request

    opener = urllib.request.build_opener(urllib.request.ProxyHandler({}),
                                         urllib.request.HTTPSHandler(context=context))
    try:
        with opener.open(url, timeout=OPEN_TIMEOUT_S) as resp:
            body = resp.read(65536)
    except urllib.error.HTTPError as exc:  # 503 while the engine is down: still its state
        body = exc.read(65536)
    except (OSError, ValueError):
        return None
    try:
        data = json.loads(body)
    except ValueError:
        return None
    return data if isinstance(data, dict) else None


@dataclass
class Options:
    """What the user told the checker about the gateway."""

    url: str
    token: str
    robot_id: int = 0
    peer_id: int | None = None
    peer_token: str | None = None
    operator_token: str | None = None
    map: str = "lab"
    cafile: str | None = None
    robot_version: ProtocolVersion = PROTOCOL_VERSION
    """The protocol version the checker's robots speak (3: no ``ack``; 2: an ``ack`` per
    action)."""

    def robot_token(self, robot: int) -> str | None:
        """The token of ``robot``: ``--token`` (a ``{id}`` template works for any robot) or
        ``--peer-token`` for the peer."""
        if "{id}" in self.token:
            return self.token.replace("{id}", str(robot))
        if robot == self.robot_id:
            return self.token
        if robot == self.peer and self.peer_token is not None:
            return self.peer_token
        return None

    @property
    def peer(self) -> int:
        """The second robot of the two-robot checks."""
        return self.peer_id if self.peer_id is not None else self.robot_id + 1


@dataclass
class Layout:
    """Where the checker's plans go on the gateway's map: a free row segment ``lane`` of five
    cells and a free cell for every other robot (they stay put)."""

    lane: list[Cell]
    spare: list[Cell]

    def paths(self, moving: dict[int, list[Cell]]) -> list[list[Cell]]:
        """A plan: the given robots' paths, a one-cell path for every other robot."""
        n = max(moving) + 1
        spare = iter(self.spare)
        return [moving[r] if r in moving else [next(spare)] for r in range(n)]


def find_layout(rows: list[str], robots: int) -> Layout:
    """A lane of five free cells in one row and ``robots`` other free cells."""
    for y, row in enumerate(rows):
        x = row.find(".....")
        if x < 0:
            continue
        lane = [(x + i, y) for i in range(5)]
        spare = [(cx, cy) for cy, r in enumerate(rows) for cx, ch in enumerate(r)
                 if ch == "." and (cx, cy) not in lane][:robots]
        if len(spare) == robots:
            return Layout(lane, spare)
    raise UsageProblem("the map has no row with five free cells in a line (or too few "
                       "free cells); choose another with --map")


class Operator:
    """The checker's operator connection: commands answered ``ok``, the gateway's status."""

    def __init__(self, conn: Conn) -> None:
        self.conn = conn
        self.status = ""
        self.snapshot: Snapshot | None = None
        self.refusals: list[Event] = []
        """The ``refused`` events received (REFUSE-2)."""
        conn.on_message = self._watch

    def _watch(self, msg: AnyMessage) -> None:
        if isinstance(msg, Snapshot):
            self.status, self.snapshot = msg.status, msg
        elif isinstance(msg, Event) and msg.event == "status" and msg.status is not None:
            self.status = msg.status
        elif isinstance(msg, Event) and msg.event == "refused":
            self.refusals.append(msg)

    async def refusal(self, timeout: float = 5.0) -> Event:
        """The first ``refused`` event not taken yet (CheckFailed if none comes in time)."""
        loop = asyncio.get_running_loop()
        end = loop.time() + timeout
        while not self.refusals:
            if loop.time() >= end or self.conn.is_closed:
                raise CheckFailed(f"no operator event refused within {timeout:g} s")
            await self.conn.wait_change(end - loop.time())
        return self.refusals.pop(0)

    async def command(self, kind: type[OperatorCommand], timeout: float = 10.0,
                      **fields: Any) -> Ok:
        """Send an operator command; CheckFailed unless it is accepted."""
        ref = await self.conn.send(kind, **fields)
        reply = await self.conn.expect(f"reply to {kind.__name__}",
                                       lambda m: isinstance(m, Ok | Error) and m.ref == ref,
                                       timeout)
        if isinstance(reply, Error):
            raise CheckFailed(f"the gateway refused the operator's {reply.ref and kind.__name__}"
                              f": {reply.code.value}: {reply.detail}")
        assert isinstance(reply, Ok)
        return reply

    async def until(self, *statuses: str, timeout: float = 10.0) -> None:
        """Wait until the gateway's status is one of ``statuses``."""
        loop = asyncio.get_running_loop()
        end = loop.time() + timeout
        while self.status not in statuses:
            if loop.time() > end:
                raise CheckFailed(f"the gateway's status stayed {self.status!r}, expected "
                                  f"{' or '.join(statuses)}")
            if self.conn.is_closed:
                raise CheckFailed("the operator connection closed")
            await asyncio.sleep(0.02)


class Robot:
    """A robot the checker plays on one connection: what it received and reported."""

    def __init__(self, target: Target, robot_id: int, conn: Conn) -> None:
        self.target = target
        self.id = robot_id
        self.conn = conn
        self.welcome: Welcome | None = None
        self.actions: dict[str, Action] = {}
        self.done: set[str] = set()  # finished or cancelled
        self.started: set[str] = set()
        self.paused = False
        conn.version = target.options.robot_version

    async def ack(self, aid: str) -> None:
        """Acknowledge ``aid`` with an ``ack`` if the connection's version has one (v1, v2;
        a v3 robot's ``started`` acknowledges it)."""
        if (self.conn.version or PROTOCOL_VERSION) < FOLDED_ACK:
            await self.conn.send(Ack, action_id=aid)

    async def hello(self, timeout: float = 5.0, **fields: Any) -> Welcome:
        """Say hello; the welcome (its resend list is taken as received actions)."""
        await self.conn.send(Hello, robot_id=self.id, **fields)
        self.welcome = await self.conn.expect_type(Welcome, timeout)
        self.paused = self.welcome.paused
        for a in self.welcome.resend:
            self.actions.setdefault(a.action_id, a)
        return self.welcome

    async def action(self, index: int | None = None, timeout: float = 5.0) -> Action:
        """The next ``action`` message (of action ``index`` if given)."""
        what = "action" if index is None else f"action with index {index}"
        a = await self.conn.expect_type(
            Action, timeout, lambda m: index is None or m.sequence == index, what=what)
        self.actions.setdefault(a.action_id, a)
        return a

    def collect(self) -> list[Action]:
        """Claim every ``action`` received so far; the open actions (see open_actions)."""
        for m in self.conn.take(Action):
            assert isinstance(m, Action)
            self.actions.setdefault(m.action_id, m)
        return self.open_actions()

    async def report(self, kind: type[Started | Finished | Cancelled], aid: str) -> str:
        """Send a report about ``aid`` with the matching pose; its msg_id."""
        a = self.actions.get(aid)
        pose = (a.dst if kind is Finished else a.src) if a is not None else None
        ref = await self.conn.send(kind, action_id=aid, pose=pose)
        if kind is Started:
            self.started.add(aid)
        else:
            self.done.add(aid)
        return ref

    async def execute(self, a: Action) -> None:
        """Acknowledge, start and finish ``a``."""
        await self.ack(a.action_id)
        await self.report(Started, a.action_id)
        await self.report(Finished, a.action_id)

    def open_actions(self) -> list[Action]:
        """Received actions not finished or cancelled, in index order."""
        todo = [a for aid, a in self.actions.items() if aid not in self.done]
        return sorted(todo, key=lambda a: parse_action_id(a.action_id))

    async def autopilot(self) -> None:
        """Execute everything held and everything that arrives, honour cancel and pause
        (runs until cancelled)."""
        while True:
            for m in self.conn.take():
                if isinstance(m, Action):
                    self.actions.setdefault(m.action_id, m)
                elif isinstance(m, CancelAction) and m.action_id not in self.done \
                        and m.action_id not in self.started:
                    await self.report(Cancelled, m.action_id)
                elif isinstance(m, Pause):
                    self.paused = True
                elif isinstance(m, Resume):
                    self.paused = False
            todo = self.open_actions()
            if todo and not self.paused:
                a = todo[0]
                if a.action_id not in self.started:
                    await self.ack(a.action_id)
                    await self.report(Started, a.action_id)
                await self.report(Finished, a.action_id)
                continue
            if self.conn.is_closed:
                return
            await self.conn.wait_change(0.2)


@dataclass
class Target:
    """The gateway under test and the checker's state of it."""

    options: Options
    breaches: Breaches = field(default_factory=Breaches)
    operator: Operator | None = None
    layout: Layout | None = None
    setup_error: str | None = None
    _restore: dict[str, Any] = field(default_factory=dict)

    def url(self, query: str = "") -> str:
        """The websocket URL, with ``query`` appended."""
        parts = urlsplit(self.options.url)
        q = "&".join(p for p in (parts.query, query) if p)
        return urlunsplit((parts.scheme, parts.netloc, parts.path, q, ""))

    def ssl_context(self) -> ssl.SSLContext | None:
        """The TLS context for ``wss://`` (trusting ``--cafile`` if given)."""
        if not self.options.url.startswith("wss://"):
            return None
        return ssl.create_default_context(cafile=self.options.cafile)

    async def open(self, token: str | None, name: str = "", query: str = "",
                   ignore: tuple[type[AnyMessage], ...] = (), **kw: Any) -> Conn:
        """A new connection with ``token`` as bearer (none if None)."""
        headers = {"Authorization": f"Bearer {token}"} if token else {}
        ws = await connect(self.url(query), additional_headers=headers, proxy=None,
                           compression=None, open_timeout=OPEN_TIMEOUT_S, ssl=self.ssl_context(),
                           max_size=4 * 1024 * 1024, **kw)
        return Conn(ws, self.breaches, name, ignore)

    async def robot(self, robot_id: int | None = None, *, hello: bool = True,
                    **hello_fields: Any) -> Robot:
        """A new connection for robot ``robot_id`` (the robot under test by default), after
        ``hello`` unless told otherwise."""
        r = self.options.robot_id if robot_id is None else robot_id
        token = self.options.robot_token(r)
        if token is None:
            raise CheckFailed(f"not run: needs the token of robot {r} (--peer-token, or a "
                              "{id} template in --token)")
        robot = Robot(self, r, await self.open(token, f"r{r}"))
        if hello:
            await robot.hello(**hello_fields)
        return robot

    # ------------------------------------------------------------------ setup
    async def probe(self) -> None:
        """Refuse a busy gateway before any robot id is used (:meth:`not_busy`), then connect
        once with the robot token: unreachable or refused is a usage problem."""
        await self.not_busy()
        try:
            conn = await self.open(self.options.robot_token(self.options.robot_id))
        except InvalidStatus as exc:
            raise UsageProblem(f"{self.options.url} refused --token (HTTP "
                               f"{exc.response.status_code})") from None
        except (OSError, TimeoutError) as exc:
            raise UsageProblem(f"cannot reach {self.options.url}: "
                               f"{exc.strerror or exc if isinstance(exc, OSError) else 'timeout'}"
                               ) from None
        except Exception as exc:  # e.g. not a websocket server at all
            raise UsageProblem(f"cannot open a websocket to {self.options.url}: {exc}") from None
        await conn.close()

    def health_url(self) -> str:
        """The gateway's ``/healthz`` beside its websocket URL (http or https)."""
        parts = urlsplit(self.options.url)
        scheme = "https" if parts.scheme == "wss" else "http"
        return urlunsplit((scheme, parts.netloc, "/healthz", "", ""))

    async def not_busy(self) -> None:
        """UsageProblem if the gateway's ``/healthz`` says it runs a fleet (a run or shift
        under way, or robots connected): the checker plays robots by id and would kick the
        real ones off. A gateway without a readable ``/healthz`` is taken as idle."""
        health = await asyncio.to_thread(read_health, self.health_url(), self.ssl_context())
        if health is None:
            return
        status, robots = health.get("gateway"), health.get("robots")
        connected = robots if isinstance(robots, int) else 0
        if status in BUSY or connected > 0:
            raise UsageProblem(f"the gateway is busy ({status}, {connected} robot(s) "
                               "connected): the checker plays robots and would disturb them; "
                               "run it on an idle gateway")

    async def setup(self) -> None:
        """Open the operator channel, choose the plan layout, switch replanning off (runs
        must only replan when a check asks). A failure is kept in :attr:`setup_error`."""
        if self.options.operator_token is None:
            self.setup_error = "not run: needs --operator-token (to load the checker's plans)"
            return
        try:
            conn = await self.open(self.options.operator_token, "op", ignore=(Event,))
        except InvalidStatus as exc:
            raise UsageProblem(f"the gateway refused --operator-token (HTTP "
                               f"{exc.response.status_code})") from None
        op = Operator(conn)
        try:
            await conn.expect_type(Snapshot, 5.0)
            if op.status not in ("empty", "loaded", "done"):
                raise CheckFailed(f"not run: the gateway is busy ({op.status}); run the "
                                  "checker on an idle gateway")
            snap = op.snapshot
            assert snap is not None
            if not snap.rows or snap.map_name != self.options.map:
                await op.command(LoadInstance, map=self.options.map, agents=1,
                                 generate={"seed": 0}, timeout=30.0)
                await conn.expect_type(Snapshot, 5.0, lambda s: bool(s.rows))
            snap = op.snapshot
            assert snap is not None
            self._restore = {"policy": snap.policy}
            await op.command(SetPolicy, policy="none")
            opts = self.options
            self.layout = find_layout(snap.rows, max(opts.robot_id, opts.peer) + 1)
            self.operator = op
        except CheckFailed as exc:
            self.setup_error = str(exc)
            await conn.close()

    async def teardown(self) -> None:
        """Give the gateway its replanning policy back; close the operator channel."""
        if self.operator is not None:
            with contextlib.suppress(CheckFailed, OSError):
                await self.operator.command(SetPolicy, **self._restore)
            await self.operator.conn.close()

    def need_operator(self) -> tuple[Operator, Layout]:
        """The operator channel and layout, or CheckFailed saying why the check cannot run."""
        if self.operator is None or self.layout is None:
            raise CheckFailed(self.setup_error or "not run: no operator channel")
        return self.operator, self.layout


class Run:
    """One execution of a tiny plan on the gateway: loaded on entry; on exit every robot of
    the plan is driven to the end (whatever the check left undone), so the next can load."""

    def __init__(self, target: Target, moving: dict[int, list[Cell]]) -> None:
        self.target = target
        self.moving = moving
        self.robots: dict[int, Robot] = {}

    async def __aenter__(self) -> Run:
        op, layout = self.target.need_operator()
        await op.until("empty", "loaded", "done")
        await op.command(LoadPlan, map=self.target.options.map,
                         paths=layout.paths(self.moving))
        return self

    async def robot(self, r: int, **hello_fields: Any) -> Robot:
        """Connect robot ``r`` of this run (and say hello)."""
        robot = await self.target.robot(r, **hello_fields)
        old = self.robots.get(r)
        if old is not None:  # keep what the robot knows across its connections
            robot.actions, robot.done, robot.started = old.actions, old.done, old.started
            for a in robot.welcome.resend if robot.welcome else []:
                robot.actions.setdefault(a.action_id, a)
        self.robots[r] = robot
        return robot

    async def start(self) -> None:
        """Start the execution."""
        op, _ = self.target.need_operator()
        await op.command(Start)

    async def __aexit__(self, *exc: object) -> None:
        op, _ = self.target.need_operator()
        if op.status == "paused":
            await op.command(Resume)
        pilots = []
        for r in self.moving:
            robot = self.robots.get(r)
            if robot is None or robot.conn.is_closed or robot.welcome is None:
                if robot is not None:
                    await robot.conn.close()
                held = [a.action_id for a in robot.open_actions()] if robot else []
                robot = await self.robot(r, acked=held)
            pilots.append(asyncio.create_task(robot.autopilot()))
        try:
            if op.status not in ("loaded", "empty"):
                await op.until("done", timeout=15.0)
        finally:
            for p in pilots:
                p.cancel()
            await asyncio.gather(*pilots, return_exceptions=True)
            for robot in self.robots.values():
                await robot.conn.close()
