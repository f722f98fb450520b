"""The checklist a gateway goes through: the checker plays robots (and an operator, to load
tiny plans) against it. Each check cites its rule in docs/protocol.md."""

from __future__ import annotations

import asyncio
import contextlib
import json
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from websockets.exceptions import ConnectionClosed, InvalidStatus

from conformance.checklist import Checklist, add_envelope_checks
from conformance.report import CheckFailed, CheckResult
from conformance.target import Cell, Options, Robot, Run, Target
from protocol import (
    MAX_MESSAGE_BYTES,
    Ack,
    Action,
    ActionRefused,
    AnyMessage,
    CancelAction,
    Cancelled,
    Error,
    ErrorCode,
    Event,
    Finished,
    Hello,
    IntruderReport,
    LoadPlan,
    Pause,
    ReplanNow,
    Resume,
    Snapshot,
    Start,
    Started,
    State,
    Unblocked,
    Welcome,
    encode,
    parse_action_id,
)
from protocol import Blocked as BlockedReport
from protocol.messages import ProtocolVersion

GATEWAY_CHECKS: Checklist[Target] = Checklist()
check = GATEWAY_CHECKS.check

QUIET_S = 0.25
"""How long the checker waits to be sure something does not happen."""

HARD_FRAME = 300_000
"""A frame larger than any gateway should read (fleetgate closes above 256 KiB)."""


def _raw(conn_name: str, **fields: Any) -> str:
    return json.dumps({"v": 1, "msg_id": f"{conn_name}-raw", "seq": 0, **fields})


def _lane(t: Target) -> list[Cell]:
    _, layout = t.need_operator()
    return layout.lane


def _single(t: Target) -> Run:
    """A run in which the robot under test makes three moves along the lane."""
    return Run(t, {t.options.robot_id: _lane(t)[1:]})


async def _started_run(t: Target) -> tuple[Run, Robot, Action]:
    run = await _single(t).__aenter__()
    robot = await run.robot(t.options.robot_id)
    await run.start()
    return run, robot, await robot.action(0)


class _Started:
    """``async with _Started(t) as (run, robot, first)``: a single run, started."""

    def __init__(self, t: Target) -> None:
        self.t = t
        self.run: Run | None = None

    async def __aenter__(self) -> tuple[Run, Robot, Action]:
        self.run, robot, first = await _started_run(self.t)
        return self.run, robot, first

    async def __aexit__(self, *exc: object) -> None:
        if self.run is not None:
            await self.run.__aexit__(*exc)


def _other(t: Target) -> int:
    return t.options.peer


# ---------------------------------------------------------------------- authentication
@check("auth-missing-token-401", "AUTH-2")
async def _auth_missing(t: Target) -> None:
    """A handshake without a token is refused with HTTP 401."""
    await _refused(t, None, 401)


@check("auth-unknown-token-403", "AUTH-3")
async def _auth_unknown(t: Target) -> None:
    """A handshake with an unknown token is refused with HTTP 403."""
    await _refused(t, "conformance-no-such-token-7f3a", 403)


async def _refused(t: Target, token: str | None, status: int) -> None:
    try:
        conn = await t.open(token)
    except InvalidStatus as exc:
        if exc.response.status_code != status:
            raise CheckFailed(f"refused with HTTP {exc.response.status_code}, expected "
                              f"{status}") from None
        return
    await conn.close()
    raise CheckFailed("the handshake was accepted")


@check("auth-token-in-query", "AUTH-1")
async def _auth_query(t: Target) -> None:
    """A token in ``?token=`` is accepted like the bearer header."""
    token = t.options.robot_token(t.options.robot_id)
    conn = await t.open(None, "rq", query=f"token={token}")
    try:
        robot = Robot(t, t.options.robot_id, conn)
        await robot.hello()
    finally:
        await conn.close()


@check("hello-gets-welcome", "HS-2")
async def _hello_welcome(t: Target) -> None:
    """``hello`` is answered with ``welcome`` for the robot, before anything else."""
    robot = await t.robot(hello=False)
    try:
        await robot.conn.send(Hello, robot_id=robot.id)
        first = await robot.conn.expect("a first message", lambda m: True)
        if not isinstance(first, Welcome):
            raise CheckFailed(f"the first message after hello is {first.type}")
        if first.robot_id != robot.id:
            raise CheckFailed(f"welcome.robot_id is {first.robot_id}, expected {robot.id}")
    finally:
        await robot.conn.close()


async def _served_in(t: Target, version: ProtocolVersion) -> None:
    """A robot speaking ``version`` is answered in it (welcome and actions) and executes its
    first action (with an ``ack`` before 3) without an ``error``."""
    async with _single(t) as run:
        robot = await t.robot(hello=False)
        robot.conn.version = version
        run.robots[robot.id] = robot
        welcome = await robot.hello()
        await run.start()
        first = await robot.action(0)
        await robot.execute(first)
        got: list[Welcome | Action] = [welcome, first, *welcome.resend]
        late = [f"{m.type} v{m.v}" for m in got if m.v != version]
        if late:
            raise CheckFailed(f"a version {version} robot got messages of another version: "
                              f"{late}")
        errors = [f"{m.code.value}: {m.detail}" for m in robot.conn.received
                  if isinstance(m, Error)]
        if errors:
            raise CheckFailed(f"a version {version} robot's messages were refused: {errors}")


@check("version-1-robot-is-served", "VER-2")
async def _version_1(t: Target) -> None:
    """A robot whose `hello` is version 1 is answered in version 1 (welcome and actions) on
    a plan without headings."""
    await _served_in(t, 1)


@check("version-2-robot-acks-and-is-served", "VER-2")
async def _version_2(t: Target) -> None:
    """A robot whose `hello` is version 2 (it acknowledges with ``ack``) is answered in
    version 2 (welcome and actions), its ``ack`` taken."""
    await _served_in(t, 2)


@check("hello-as-another-robot", "AUTH-4")
async def _hello_other(t: Target) -> None:
    """``hello`` claiming another robot id gets ``not_yourself`` and no welcome."""
    robot = await t.robot(hello=False)
    try:
        ref = await robot.conn.send(Hello, robot_id=_other(t))
        await robot.conn.error_for(ref, ErrorCode.NOT_YOURSELF)
        await robot.conn.quiet("welcome", lambda m: isinstance(m, Welcome), QUIET_S)
    finally:
        await robot.conn.close()


# ---------------------------------------------------------------------- refusals
RobotFields = Callable[[Target, Robot], dict[str, Any]]


@dataclass(frozen=True)
class Refusal:
    """A check that a connected robot's message of type ``kind`` (with ``fields``) gets an
    ``error`` with ``code`` naming it (after ``hello`` unless ``hello`` is false)."""

    name: str
    rule: str
    doc: str
    code: ErrorCode
    kind: type[AnyMessage]
    fields: RobotFields
    hello: bool = True

    async def __call__(self, t: Target) -> None:
        robot = await t.robot(hello=self.hello)
        try:
            ref = await robot.conn.send(self.kind, **self.fields(t, robot))
            await robot.conn.error_for(ref, self.code)
        finally:
            await robot.conn.close()


REFUSALS = [
    Refusal("report-about-another-robot", "AUTH-5",
            "A report about another robot's action gets ``not_yourself``.",
            ErrorCode.NOT_YOURSELF, Finished, lambda t, r: {"action_id": f"0.{_other(t)}.0"}),
    Refusal("state-about-another-robot", "AUTH-5",
            "A ``state`` naming another robot gets ``not_yourself``.",
            ErrorCode.NOT_YOURSELF, State, lambda t, r: {"robot_id": _other(t)}),
    Refusal("robot-may-not-command", "AUTH-6",
            "An operator command from a robot gets ``forbidden``.",
            ErrorCode.FORBIDDEN, Start, lambda t, r: {}),
    Refusal("robot-may-not-report-intruders", "AUTH-6",
            "A world report (``intruder``) from a robot gets ``forbidden``.",
            ErrorCode.FORBIDDEN, IntruderReport, lambda t, r: {"cell": (0, 0), "state": "on"}),
    Refusal("report-before-hello", "HS-4", "A report before ``hello`` gets ``bad_state``.",
            ErrorCode.BAD_STATE, Started, lambda t, r: {"action_id": f"0.{r.id}.0"},
            hello=False),
]
"""Messages a robot may not send (yet)."""
for _r in REFUSALS:
    GATEWAY_CHECKS.add(_r.name, _r.rule, _r, _r.doc)


@check("second-hello-resyncs", "HS-5")
async def _second_hello(t: Target) -> None:
    """A second ``hello`` on one connection gets a second ``welcome``."""
    robot = await t.robot()
    try:
        await robot.hello()
    finally:
        await robot.conn.close()


@check("new-connection-replaces-old", "HS-6")
async def _replaced(t: Target) -> None:
    """A robot's new connection replaces its old one, which is closed with 4000."""
    old = await t.robot()
    new = await t.robot()
    try:
        code = await old.conn.closed()
        if code != 4000:
            raise CheckFailed(f"the old connection was closed with {code}, expected 4000")
        if new.conn.is_closed:
            raise CheckFailed("the new connection was closed")
    finally:
        await old.conn.close()
        await new.conn.close()


@check("state-accepted", "STATE-2")
async def _state_ok(t: Target) -> None:
    """A robot's own ``state`` is accepted silently."""
    robot = await t.robot()
    try:
        await robot.conn.send(State, robot_id=robot.id, activity="idle")
        await robot.conn.quiet("error", lambda m: isinstance(m, Error), QUIET_S)
    finally:
        await robot.conn.close()


# ---------------------------------------------------------------------- bad messages
@dataclass(frozen=True)
class BadFrame:
    """A check that a frame, sent by a robot (after ``hello`` unless ``hello`` is false),
    gets an ``error`` with ``code`` and ``ref`` (the offending msg_id, or null if the gateway
    cannot read one); with ``usable_after``, a ``hello`` on the same connection is then still
    welcomed."""

    name: str
    rule: str
    doc: str
    frame: Callable[[Target], str | bytes]
    code: ErrorCode
    ref: str | None = None
    timeout: float = 5.0
    hello: bool = True
    usable_after: bool = False

    async def __call__(self, t: Target) -> None:
        robot = await t.robot(hello=self.hello)
        try:
            await robot.conn.send_raw(self.frame(t))
            await robot.conn.error_for(self.ref, self.code, self.timeout)
            if self.usable_after:
                await robot.hello()
        finally:
            await robot.conn.close()


def _long_number(t: Target) -> str:
    raw = _raw("num", type="state", robot_id=t.options.robot_id, battery=0.5)
    return raw.replace('"battery": 0.5', '"battery": 0.' + "5" * 40)


BAD_FRAMES = [
    BadFrame("malformed-json", "ERR-3", "Text that is not JSON gets ``malformed`` with ``ref`` "
             "null.", lambda t: "{not json", ErrorCode.MALFORMED),
    BadFrame("not-a-json-object", "MSG-1", "A JSON value that is not an object gets "
             "``malformed``.", lambda t: "[1, 2]", ErrorCode.MALFORMED),
    BadFrame("unsupported-version", "VER-1", "``v`` 4 (not 1, 2 or 3) gets ``unsupported_version`` "
             "naming the msg_id.",
             lambda t: _raw("x", type="state", robot_id=t.options.robot_id, v=4),
             ErrorCode.UNSUPPORTED_VERSION, "x-raw"),
    BadFrame("missing-version", "VER-1", "A message without ``v`` gets "
             "``unsupported_version``.",
             lambda t: json.dumps({"type": "state", "msg_id": "y-raw", "seq": 0,
                                   "robot_id": t.options.robot_id}),
             ErrorCode.UNSUPPORTED_VERSION, "y-raw"),
    BadFrame("unknown-type", "MSG-1", "An unknown ``type`` gets ``unknown_type`` naming the "
             "msg_id.", lambda t: _raw("z", type="teleport"), ErrorCode.UNKNOWN_TYPE, "z-raw"),
    BadFrame("invalid-field", "MSG-1", "A field of the wrong form gets ``invalid`` naming the "
             "msg_id.", lambda t: _raw("w", type="ack", action_id="nonsense"),
             ErrorCode.INVALID, "w-raw"),
    BadFrame("unknown-field", "MSG-1", "An unknown field gets ``invalid`` (no extra fields).",
             lambda t: _raw("u", type="state", robot_id=t.options.robot_id, colour="red"),
             ErrorCode.INVALID, "u-raw"),
    BadFrame("binary-frame-refused", "WS-1", "A binary frame gets ``malformed`` (messages "
             "travel in text frames).",
             lambda t: encode(State(msg_id="bin-0", seq=0, robot_id=t.options.robot_id)).encode(),
             ErrorCode.MALFORMED, timeout=2.0),
    BadFrame("deep-nesting-refused", "LIMIT-6", "A message nested deeper than 8 levels gets "
             "`too_large` before it is parsed.",
             lambda t: _raw("deep", type="state", robot_id=t.options.robot_id,
                            pad=json.loads("[" * 20 + "]" * 20)), ErrorCode.TOO_LARGE),
    BadFrame("long-number-refused", "LIMIT-6", "A number of more than 32 digits gets "
             "`too_large` before it is parsed.", _long_number, ErrorCode.TOO_LARGE),
    BadFrame("too-large", "LIMIT-1", "A message over 64 KiB gets ``too_large`` and the "
             "connection stays open.",
             lambda t: _raw("big", type="state", robot_id=t.options.robot_id,
                            pad="x" * MAX_MESSAGE_BYTES), ErrorCode.TOO_LARGE,
             usable_after=True),
    BadFrame("error-keeps-connection", "ERR-2", "After an ``error`` reply the connection "
             "stays usable.", lambda t: "{not json", ErrorCode.MALFORMED, hello=False,
             usable_after=True),
]
"""Frames a gateway must refuse, each with its error code."""
for _f in BAD_FRAMES:
    GATEWAY_CHECKS.add(_f.name, _f.rule, _f, _f.doc)


@check("oversize-frame-closes-1009", "LIMIT-2")
async def _huge(t: Target) -> None:
    """A frame far over the limit closes the connection with 1009."""
    robot = await t.robot(hello=False)
    try:
        with contextlib.suppress(ConnectionClosed):
            await robot.conn.send_raw(_raw("huge", type="state", robot_id=robot.id,
                                           pad="x" * HARD_FRAME))
        code = await robot.conn.closed()
        if code != 1009:
            raise CheckFailed(f"closed with {code}, expected 1009")
    finally:
        await robot.conn.close()


async def _flood(robot: Robot, text: str, times: int) -> None:
    """Send ``text`` up to ``times`` times, or until the gateway closes the connection."""
    for _ in range(times):
        if robot.conn.is_closed:
            return
        try:
            await robot.conn.send_raw(text)
        except ConnectionClosed:
            return


@check("repeated-abuse-closes-1008", "LIMIT-4")
async def _abuse(t: Target) -> None:
    """Repeated bad messages close the connection with 1008, after their error replies."""
    robot = await t.robot(hello=False)
    try:
        await _flood(robot, "[]", 200)
        code = await robot.conn.closed()
        errors = [m for m in robot.conn.received if isinstance(m, Error)]
        if code != 1008:
            raise CheckFailed(f"closed with {code}, expected 1008")
        if not errors or any(e.code != ErrorCode.MALFORMED for e in errors):
            raise CheckFailed(f"expected malformed errors before the close, got "
                              f"{[e.code.value for e in errors][:5]}")
    finally:
        await robot.conn.close()


@check("rate-limited", "LIMIT-3", required=False)
async def _rate(t: Target) -> None:
    """A flood of messages gets ``rate_limited``."""
    robot = await t.robot()
    try:
        text = encode(State(msg_id="flood", seq=0, robot_id=robot.id))
        await _flood(robot, text, 3000)
        await robot.conn.expect_type(Error, 5.0, lambda e: e.code == ErrorCode.RATE_LIMITED,
                                     what="error rate_limited")
    finally:
        await robot.conn.close()


@check("gateway-answers-ping", "WS-2")
async def _ping(t: Target) -> None:
    """A websocket ping is answered with a pong."""
    robot = await t.robot(hello=False)
    try:
        pong = await robot.conn.ws.ping()
        try:
            await asyncio.wait_for(pong, 5.0)
        except TimeoutError:
            raise CheckFailed("no pong within 5 s") from None
    finally:
        await robot.conn.close()


# ---------------------------------------------------------------------- dispatch
@check("welcome-start-pose", "HS-3")
async def _welcome_start(t: Target) -> None:
    """Before a run, ``welcome.start`` is the robot's first cell of the loaded plan."""
    async with _single(t) as run:
        robot = await run.robot(t.options.robot_id)
        assert robot.welcome is not None
        want = _lane(t)[1]
        got = robot.welcome.start.cell if robot.welcome.start else None
        if got != want:
            raise CheckFailed(f"welcome.start is {got}, expected {want}")


@check("dispatch-fields", "DISPATCH-2")
async def _dispatch_fields(t: Target) -> None:
    """The first action: id ``<plan>.<robot>.0``, sequence 0, src/dst the path's first step."""
    async with _Started(t) as (_, robot, first):
        lane = _lane(t)
        _plan, r, index = parse_action_id(first.action_id)
        problems = []
        if (r, index) != (robot.id, 0):
            problems.append(f"action_id {first.action_id} is not action 0 of robot {robot.id}")
        if first.sequence != index:
            problems.append(f"sequence {first.sequence} != index {index}")
        if (tuple(first.src.cell), tuple(first.dst.cell)) != (lane[1], lane[2]):
            problems.append(f"{first.src.cell} -> {first.dst.cell}, expected {lane[1]} -> "
                            f"{lane[2]}")
        if problems:
            raise CheckFailed("; ".join(problems))


@check("dispatch-in-order", "DISPATCH-3")
async def _in_order(t: Target) -> None:
    """Every action of the plan arrives once, in index order, each starting where the last
    ended."""
    async with _Started(t) as (_, robot, first):
        got = [first]
        await robot.execute(first)
        while len(got) < 3:
            a = await robot.action()
            got.append(a)
            await robot.execute(a)
        ids = [parse_action_id(a.action_id)[2] for a in got]
        if ids != [0, 1, 2]:
            raise CheckFailed(f"action indexes arrived as {ids}")
        lane = _lane(t)
        cells = [tuple(got[0].src.cell)] + [tuple(a.dst.cell) for a in got]
        if cells != lane[1:]:
            raise CheckFailed(f"the actions visit {cells}, the plan is {lane[1:]}")
        await robot.conn.quiet("action", lambda m: isinstance(m, Action), QUIET_S)


@check("run-completes", "REPORT-1")
async def _completes(t: Target) -> None:
    """``started`` + ``finished`` of every action completes the run (status ``done``)."""
    op, _ = t.need_operator()
    async with _Started(t) as (_, robot, first):
        await robot.execute(first)
        for _ in range(2):
            await robot.execute(await robot.action())
        await op.until("done", timeout=5.0)
        errors = [m for m in robot.conn.received if isinstance(m, Error)]
        if errors:
            raise CheckFailed(f"the gateway refused a report: {errors[0].code.value}: "
                              f"{errors[0].detail}")


ActionFields = Callable[[Robot, Action], dict[str, Any]]


def _at_src(robot: Robot, a: Action) -> dict[str, Any]:
    return {"action_id": a.action_id, "pose": a.src}


def _at_dst(robot: Robot, a: Action) -> dict[str, Any]:
    return {"action_id": a.action_id, "pose": a.dst}


def _never_sent(robot: Robot, a: Action) -> dict[str, Any]:
    return {"action_id": f"0.{robot.id}.9"}


@dataclass(frozen=True)
class RunRefusal:
    """A check that, in a fresh run started with the robot's first action dispatched, the
    robot's ``messages`` (type and fields from the robot and that action), sent in order, end
    in an ``error`` with ``code`` for the last one."""

    name: str
    rule: str
    doc: str
    code: ErrorCode
    messages: tuple[tuple[type[AnyMessage], ActionFields], ...]

    async def __call__(self, t: Target) -> None:
        async with _Started(t) as (_, robot, first):
            ref = ""
            for kind, fields in self.messages:
                ref = await robot.conn.send(kind, **fields(robot, first))
            await robot.conn.error_for(ref, self.code)


RUN_REFUSALS = [
    RunRefusal("ack-unknown-action", "ACK-2", "An ``ack`` of an action never dispatched gets "
               "``unknown_action``.", ErrorCode.UNKNOWN_ACTION, ((Ack, _never_sent),)),
    RunRefusal("report-never-dispatched", "REPORT-3", "A report about an action never "
               "dispatched gets ``unknown_action``.", ErrorCode.UNKNOWN_ACTION,
               ((Started, _never_sent),)),
    RunRefusal("finish-before-start", "REPORT-1", "``finished`` without ``started`` gets "
               "``rejected``.", ErrorCode.REJECTED, ((Finished, _at_dst),)),
    RunRefusal("started-twice", "REPORT-4", "A second ``started`` of a running action gets "
               "``duplicate``.", ErrorCode.DUPLICATE, ((Started, _at_src), (Started, _at_src))),
    RunRefusal("blocked-twice", "REPORT-4", "A second ``blocked`` gets ``duplicate``.",
               ErrorCode.DUPLICATE, ((BlockedReport, _at_src), (BlockedReport, _at_src))),
    RunRefusal("unblocked-when-not-blocked", "BLOCK-2", "``unblocked`` of an action that is "
               "not blocked gets ``rejected``.", ErrorCode.REJECTED, ((Unblocked, _at_src),)),
    RunRefusal("cancelled-without-cancel", "CANCEL-5", "``cancelled`` with no ``cancel`` "
               "outstanding gets ``rejected``.", ErrorCode.REJECTED, ((Cancelled, _at_src),)),
]
"""Reports and acks out of turn in a run, each with its error code."""
for _rr in RUN_REFUSALS:
    GATEWAY_CHECKS.add(_rr.name, _rr.rule, _rr, _rr.doc)


@check("finished-twice-applied-once", "DUP-2")
async def _finished_twice(t: Target) -> None:
    """A second ``finished`` gets ``duplicate`` and changes nothing (no action is sent
    again)."""
    async with _Started(t) as (_, robot, first):
        await robot.execute(first)
        second = await robot.action(1)
        ref = await robot.conn.send(Finished, action_id=first.action_id, pose=first.dst)
        await robot.conn.error_for(ref, ErrorCode.DUPLICATE)
        await robot.conn.quiet(f"second dispatch of {second.action_id}",
                               lambda m: isinstance(m, Action)
                               and m.action_id in (first.action_id, second.action_id), QUIET_S)


@check("out-of-order-report", "DISPATCH-4")
async def _out_of_order(t: Target) -> None:
    """``started`` of action 1 while action 0 is unfinished is refused."""
    async with _Started(t) as (_, robot, _first):
        ref = await robot.conn.send(Started, action_id=f"0.{robot.id}.1")
        err = await robot.conn.expect_type(Error, 5.0, lambda e: e.ref == ref,
                                           what=f"error for {ref}")
        if err.code not in (ErrorCode.REJECTED, ErrorCode.UNKNOWN_ACTION):
            raise CheckFailed(f"got {err.code.value}, expected rejected (or unknown_action if "
                              "it was not dispatched yet)")


@check("blocked-then-unblocked", "BLOCK-1")
async def _blocked_ok(t: Target) -> None:
    """``blocked``, ``unblocked``, ``started``, ``finished`` of one action are accepted."""
    async with _Started(t) as (_, robot, first):
        aid = first.action_id
        await robot.conn.send(Ack, action_id=aid)
        await robot.conn.send(BlockedReport, action_id=aid, pose=first.src)
        await robot.conn.send(Unblocked, action_id=aid, pose=first.src)
        await robot.report(Started, aid)
        await robot.report(Finished, aid)
        await robot.action(1)
        await robot.conn.quiet("error", lambda m: isinstance(m, Error), QUIET_S)


@check("blocked-after-start", "BLOCK-2")
async def _blocked_late(t: Target) -> None:
    """``blocked`` of a started move (v2: stopped on the way) is accepted, so a second one is
    a ``duplicate``; of a started wait or turn it gets ``rejected``."""
    async with _Started(t) as (_, robot, first):
        await robot.report(Started, first.action_id)
        ref = await robot.conn.send(BlockedReport, action_id=first.action_id, pose=first.src)
        if first.src.cell == first.dst.cell:
            await robot.conn.error_for(ref, ErrorCode.REJECTED)
            return
        ref = await robot.conn.send(BlockedReport, action_id=first.action_id, pose=first.src)
        await robot.conn.error_for(ref, ErrorCode.DUPLICATE)


# ---------------------------------------------------------------------- reconnecting
@check("resend-unacknowledged", "RESEND-1")
async def _resend_unacked(t: Target) -> None:
    """The actions the robot never acknowledged are resent in the next `welcome`, in index
    order, as first sent."""
    async with _single(t) as run:
        robot = await run.robot(t.options.robot_id)
        await run.start()
        await robot.action(0)
        await asyncio.sleep(QUIET_S)  # collect what a lookahead gateway releases early
        sent = robot.collect()
        await robot.conn.close()
        again = await run.robot(robot.id)
        assert again.welcome is not None
        resent = [a.action_id for a in again.welcome.resend]
        want = [a.action_id for a in sent]
        if resent != want:
            raise CheckFailed(f"welcome.resend is {resent}, expected the unacknowledged {want}")
        changed = [a.action_id for a, b in zip(sent, again.welcome.resend, strict=True)
                   if (a.src, a.dst, a.sequence) != (b.src, b.dst, b.sequence)]
        if changed:
            raise CheckFailed(f"resent actions differ from the first dispatch: {changed}")


@check("welcome-names-the-plan", "HS-3")
async def _welcome_plan(t: Target) -> None:
    """During a run `welcome.plan` is the number of the plan being executed."""
    async with _Started(t) as (run, robot, first):
        await robot.conn.send(Ack, action_id=first.action_id)
        await robot.conn.close()
        again = await run.robot(robot.id, acked=[first.action_id])
        assert again.welcome is not None
        plan = parse_action_id(first.action_id)[0]
        if again.welcome.plan != plan:
            raise CheckFailed(f"welcome.plan is {again.welcome.plan}, the actions are of plan "
                              f"{plan}")


@check("no-resend-of-acknowledged", "RESEND-1")
async def _no_resend_acked(t: Target) -> None:
    """Actions the robot acknowledged and still holds (``hello.acked``) are not resent."""
    async with _single(t) as run:
        robot = await run.robot(t.options.robot_id)
        await run.start()
        await robot.action(0)
        await asyncio.sleep(QUIET_S)  # collect what a lookahead gateway releases early
        held = [a.action_id for a in robot.collect()]
        for aid in held:
            await robot.conn.send(Ack, action_id=aid)
        await asyncio.sleep(QUIET_S)
        await robot.conn.close()
        again = await run.robot(robot.id, acked=held)
        assert again.welcome is not None
        resent = [a.action_id for a in again.welcome.resend]
        if resent:
            raise CheckFailed(f"welcome.resend is {resent}: acknowledged actions {held} were "
                              "sent again")


async def _back_having_finished(t: Target, run: Run, reported: bool) -> tuple[Robot, Action]:
    """The robot starts and finishes its first action (``reported``: it sent ``finished``,
    else its link dropped first), reconnects and lists it in ``hello.finished``: its new
    connection and the action."""
    robot = await run.robot(t.options.robot_id)
    await run.start()
    first = await robot.action(0)
    await robot.conn.send(Ack, action_id=first.action_id)
    await robot.report(Started, first.action_id)
    if reported:
        await robot.report(Finished, first.action_id)
    else:
        robot.done.add(first.action_id)
    await robot.conn.close()
    return await run.robot(robot.id, finished=[first.action_id]), first


@check("finish-reported-in-hello", "RESEND-3")
async def _finish_in_hello(t: Target) -> None:
    """A finish listed in ``hello.finished`` is applied; a later ``finished`` of it gets
    ``duplicate``."""
    async with _single(t) as run:
        again, first = await _back_having_finished(t, run, reported=False)
        assert again.welcome is not None
        if any(a.action_id == first.action_id for a in again.welcome.resend):
            raise CheckFailed(f"{first.action_id} was resent although hello said finished")
        ref = await again.conn.send(Finished, action_id=first.action_id, pose=first.dst)
        await again.conn.error_for(ref, ErrorCode.DUPLICATE)


@check("running-reported-in-hello", "RESEND-4")
async def _running_in_hello(t: Target) -> None:
    """``hello.current`` running applies the ``started`` the link lost: a ``finished``
    follows without error."""
    async with _single(t) as run:
        robot = await run.robot(t.options.robot_id)
        await run.start()
        first = await robot.action(0)
        await robot.conn.send(Ack, action_id=first.action_id)
        await robot.conn.close()
        again = await run.robot(robot.id, acked=[first.action_id],
                                current={"action_id": first.action_id, "state": "running"})
        ref = await again.report(Finished, first.action_id)
        await again.conn.quiet(f"error for {ref}",
                               lambda m: isinstance(m, Error) and m.ref == ref, QUIET_S)


async def _back_holding_foreign(t: Target, run: Run) -> tuple[Robot, Action, str]:
    """The robot acknowledges its first action, reconnects and says it holds it and an action
    of another run: its new connection, the first action, the other run's action id."""
    robot = await run.robot(t.options.robot_id)
    await run.start()
    first = await robot.action(0)
    await robot.conn.send(Ack, action_id=first.action_id)
    await robot.conn.close()
    foreign = f"zz{t.options.robot_id}.0.{t.options.robot_id}.0"
    return await run.robot(robot.id, acked=[first.action_id, foreign]), first, foreign


@check("foreign-held-action-cancelled", "RESEND-5")
async def _foreign_in_hello(t: Target) -> None:
    """An action id in ``hello.acked`` that the gateway never dispatched in this run (here: of
    another run) is cancelled after the ``welcome``; its ``cancelled`` gets no error."""
    async with _single(t) as run:
        again, _, foreign = await _back_holding_foreign(t, run)
        cancel = await again.conn.expect(f"cancel of {foreign}", lambda m: isinstance(
            m, CancelAction) and m.action_id == foreign)
        assert isinstance(cancel, CancelAction)
        ref = await again.report(Cancelled, foreign)
        await again.conn.quiet(f"error for {ref}",
                               lambda m: isinstance(m, Error) and m.ref == ref, QUIET_S)


@check("foreign-held-action-dropped-in-welcome", "RESEND-5")
async def _foreign_dropped(t: Target) -> None:
    """An action of another run in ``hello.acked`` is listed in ``welcome.drop`` (the robot
    MUST drop it before it starts anything); the run's own held action is not."""
    async with _single(t) as run:
        again, first, foreign = await _back_holding_foreign(t, run)
        assert again.welcome is not None
        if foreign not in again.welcome.drop or first.action_id in again.welcome.drop:
            raise CheckFailed(f"welcome.drop is {again.welcome.drop}: expected {foreign} (of "
                              f"another run) and not {first.action_id}")


@check("finish-applied-without-repeat", "DUP-1")
async def _finish_without_repeat(t: Target) -> None:
    """A robot that implements only the MUST rules reports a ``finished`` once: listed again
    in its next ``hello`` (its link dropped after the report), the action is not resent and the
    next one arrives, without the robot repeating the ``finished``."""
    async with _single(t) as run:
        again, first = await _back_having_finished(t, run, reported=True)
        assert again.welcome is not None
        if any(a.action_id == first.action_id for a in again.welcome.resend):
            raise CheckFailed(f"{first.action_id} was resent although the robot finished it")
        if not any(a.sequence == 1 for a in again.welcome.resend):
            await again.action(1)


# ---------------------------------------------------------------------- two robots
def _pair(t: Target) -> Run:
    """Robot R moves lane[1] -> lane[2]; the peer waits on lane[0], then enters lane[1]."""
    lane = _lane(t)
    return Run(t, {t.options.robot_id: [lane[1], lane[2]],
                   t.options.peer: [lane[0], lane[0], lane[1]]})


@check("dispatch-waits-for-dependencies", "DISPATCH-1")
async def _dependencies(t: Target) -> None:
    """An action is not sent before the other robot's action it depends on has finished."""
    async with _pair(t) as run:
        robot = await run.robot(t.options.robot_id)
        peer = await run.robot(t.options.peer)
        await run.start()
        mine = await robot.action(0)
        wait = await peer.action(0)
        await peer.execute(wait)
        await peer.conn.quiet("action 1 before its dependency finished",
                              lambda m: isinstance(m, Action) and m.sequence == 1, QUIET_S)
        await robot.execute(mine)
        await peer.action(1)


@check("disconnected-robot-holds-others", "LIVE-3")
async def _held(t: Target) -> None:
    """While a robot is away its unfinished step holds the robots that depend on it."""
    async with _pair(t) as run:
        robot = await run.robot(t.options.robot_id)
        peer = await run.robot(t.options.peer)
        await run.start()
        mine = await robot.action(0)
        await robot.conn.send(Ack, action_id=mine.action_id)
        await robot.conn.close()
        await peer.execute(await peer.action(0))
        await peer.conn.quiet("action 1 while its dependency's robot is away",
                              lambda m: isinstance(m, Action) and m.sequence == 1, QUIET_S)
        back = await run.robot(robot.id, acked=[mine.action_id])
        await back.execute(mine)
        await peer.action(1)


# ---------------------------------------------------------------------- pause, cancel
@check("pause-and-resume-reach-robots", "PAUSE-1")
async def _pause(t: Target) -> None:
    """The operator's pause and resume are sent to every connected robot."""
    op, _ = t.need_operator()
    async with _Started(t) as (_, robot, _first):
        await op.command(Pause)
        await robot.conn.expect_type(Pause)
        await op.command(Resume)
        await robot.conn.expect_type(Resume)


@check("welcome-while-paused", "PAUSE-3")
async def _welcome_paused(t: Target) -> None:
    """A robot connecting while the fleet is paused is told so in ``welcome.paused``."""
    op, _ = t.need_operator()
    async with _Started(t) as (run, robot, first):
        await robot.conn.send(Ack, action_id=first.action_id)
        await op.command(Pause)
        await robot.conn.close()
        again = await run.robot(robot.id, acked=[first.action_id])
        assert again.welcome is not None
        if not again.welcome.paused:
            raise CheckFailed("welcome.paused is false while the fleet is paused")


async def _replan(t: Target) -> tuple[Run, Robot, list[CancelAction]]:
    op, _ = t.need_operator()
    run, robot, _first = await _started_run(t)
    await asyncio.sleep(QUIET_S)
    held = robot.collect()
    await op.command(ReplanNow)
    cancels = []
    for _ in held:
        cancels.append(await robot.conn.expect_type(CancelAction))
    return run, robot, cancels


@check("cancel-on-replan", "CANCEL-1")
async def _cancel(t: Target) -> None:
    """A replan cancels every dispatched action that has not started."""
    run, robot, cancels = await _replan(t)
    try:
        held = sorted(a.action_id for a in robot.open_actions())
        got = sorted(c.action_id for c in cancels)
        if got != held:
            raise CheckFailed(f"cancelled {got}, expected {held}")
    finally:
        await run.__aexit__(None, None, None)


async def _expect_plan_1_from(robot: Robot, cell: Cell) -> None:
    """Wait for the robot's first action of plan 1 and check that it starts on ``cell``
    (where the robot stands)."""
    nxt = await robot.conn.expect_type(
        Action, 15.0, lambda a: parse_action_id(a.action_id)[0] == 1,
        what="an action of plan 1")
    robot.actions[nxt.action_id] = nxt
    if tuple(nxt.src.cell) != cell:
        raise CheckFailed(f"plan 1 starts on {nxt.src.cell}, the robot is on {cell}")


@check("new-plan-after-replan", "CANCEL-6")
async def _new_plan(t: Target) -> None:
    """After the cancels are confirmed, actions of the next plan number arrive, starting
    where the robot stands."""
    run, robot, cancels = await _replan(t)
    try:
        for c in cancels:
            await robot.report(Cancelled, c.action_id)
        await _expect_plan_1_from(robot, _lane(t)[1])
    finally:
        await run.__aexit__(None, None, None)


@check("refused-action-taken-back", "REFUSE-2")
async def _refused_back(t: Target) -> None:
    """A ``refused`` action (not started) is taken back without an ``error``: the robot gets
    nothing more of the plan, the operators an event ``refused`` with the robot's reason, and
    a replan gives the robot a new plan from where it stands."""
    op, _ = t.need_operator()
    run, robot, first = await _started_run(t)
    try:
        await asyncio.sleep(QUIET_S)  # what lookahead dispatched with it has arrived
        held = robot.collect()
        await robot.conn.send(ActionRefused, action_id=first.action_id, pose=first.src,
                              code="pose_mismatch", detail="conformance")
        robot.done.update(a.action_id for a in held)
        event = await op.refusal()
        if (event.robot, event.action) != (robot.id, first.sequence) or \
                "conformance" not in (event.reason or ""):
            raise CheckFailed(f"event refused names robot {event.robot} action "
                              f"{event.action} because {event.reason!r}")
        await robot.conn.quiet("error or action", lambda m: isinstance(m, Error | Action),
                               QUIET_S)
        await op.command(ReplanNow)
        await _expect_plan_1_from(robot, (first.src.cell[0], first.src.cell[1]))
    finally:
        await run.__aexit__(None, None, None)


# ---------------------------------------------------------------------- operator channel
@check("operator-gets-snapshot", "OP-1")
async def _op_snapshot(t: Target) -> None:
    """An operator gets a `snapshot` on connect."""
    t.need_operator()
    conn = await t.open(t.options.operator_token, "op2", ignore=(Event,))
    try:
        await conn.expect_type(Snapshot, 5.0)
    finally:
        await conn.close()


@check("operator-bad-request", "OP-2")
async def _op_bad_request(t: Target) -> None:
    """A plan that is not a plan (a jump between cells) gets `bad_request`."""
    op, layout = t.need_operator()
    lane = layout.lane
    ref = await op.conn.send(LoadPlan, map=t.options.map, paths=[[lane[0], lane[2]]])
    await op.conn.error_for(ref, ErrorCode.BAD_REQUEST)


@check("operator-bad-state", "OP-2")
async def _op_bad_state(t: Target) -> None:
    """`resume` while nothing is paused gets `bad_state`."""
    op, _ = t.need_operator()
    ref = await op.conn.send(Resume)
    await op.conn.error_for(ref, ErrorCode.BAD_STATE)


# ---------------------------------------------------------------------- envelope (passive)
add_envelope_checks(GATEWAY_CHECKS, "gateway")


async def run_gateway_checks(options: Options, only: set[str] | None = None
                             ) -> list[CheckResult]:
    """Run the gateway checklist against ``options.url``; UsageProblem if it cannot start."""
    target = Target(options)
    await target.probe()
    await target.setup()
    try:
        return await GATEWAY_CHECKS.run(target, only=only)
    finally:
        await target.teardown()
