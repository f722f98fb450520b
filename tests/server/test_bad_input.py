"""Bad input against the real server (127.0.0.1, real websockets): each gets its error code,
nothing else changes, the other robots carry on and the plan still completes. The gateways run
in virtual time (no test here is about the real clock), so the suite holds at any load."""

from __future__ import annotations

import asyncio
import contextlib
import json
from collections.abc import AsyncIterator
from dataclasses import dataclass
from typing import Any

import pytest
from websockets.exceptions import ConnectionClosed, InvalidStatus

from gateway.server.gateway import Gateway
from protocol import (
    MAX_MESSAGE_BYTES,
    Action,
    Error,
    ErrorCode,
    Finished,
    Hello,
    LoadPlan,
    Start,
    Started,
    State,
)
from tests.server.conftest import LAB_PATHS, virtual_gateway
from tests.server.robots import Peer, TestRobot

pytestmark = pytest.mark.looptime  # virtual time over real websockets


@dataclass
class Fleet:
    """Robot 0 is driven by hand; robots 1 and 2 execute on their own."""

    gw: Gateway
    bad: TestRobot
    first: Action
    others: list[TestRobot]
    tasks: list[asyncio.Task[None]]


@contextlib.asynccontextmanager
async def started_fleet() -> AsyncIterator[Fleet]:
    """The lab plan started on a virtual-time gateway: robot 0 connected and sent its first
    action, robots 1 and 2 executing."""
    async with virtual_gateway() as (gateway, ws_connect):
        code, detail = await gateway.command(LoadPlan(msg_id="l", seq=0, map="lab",
                                                      paths=LAB_PATHS))
        assert code is None, detail
        bad = TestRobot(await ws_connect("demo-robot-0"), 0)
        await bad.hello()
        others = [TestRobot(await ws_connect(f"demo-robot-{i}"), i, move_s=0.05)
                  for i in (1, 2)]
        for r in others:
            await r.hello()
        tasks = [asyncio.create_task(r.run()) for r in others]
        assert await gateway.command(Start(msg_id="s", seq=1)) == (None, "started")
        first = await bad.expect(Action)
        assert first.action_id == "0.0.0"
        try:
            yield Fleet(gateway, bad, first, others, tasks)
        finally:
            for t in tasks:
                t.cancel()


def fingerprint(gw: Gateway) -> tuple[Any, ...]:
    """Everything about robot 0 and the plan that a bad message must not change."""
    ex, rec = gw.engine.executor, gw.engine.robot(0)
    assert ex is not None
    return (ex.plan_id, ex.mode, ex.replans, ex.robot_cell(0), ex.completion_ms(0),
            {k: (h.phase, h.acked, h.cancel) for k, h in rec.held.items()},
            dict(rec.applied), rec.next_index, rec.link is not None)


def _msg(**fields: Any) -> str:
    return json.dumps({"v": 1, "msg_id": "bad-1", "seq": 99, **fields})


BAD_INPUTS = [
    pytest.param("{not json", ErrorCode.MALFORMED, None, id="malformed-json"),
    pytest.param(_msg(type="teleport"), ErrorCode.UNKNOWN_TYPE, "bad-1", id="unknown-type"),
    pytest.param(_msg(type="ack", action_id="0.0.0", v=4), ErrorCode.UNSUPPORTED_VERSION,
                 "bad-1", id="wrong-version"),
    pytest.param(_msg(type="ack", action_id="nonsense"), ErrorCode.INVALID, "bad-1",
                 id="invalid-field"),
    pytest.param(_msg(type="state", robot_id=0, pad="x" * MAX_MESSAGE_BYTES),
                 ErrorCode.TOO_LARGE, None, id="oversized"),
    pytest.param(_msg(type="finished", action_id="0.1.0"), ErrorCode.NOT_YOURSELF, "bad-1",
                 id="reports-for-another-robot"),
    pytest.param(_msg(type="hello", robot_id=2), ErrorCode.NOT_YOURSELF, "bad-1",
                 id="hello-as-another-robot"),
    pytest.param(_msg(type="start"), ErrorCode.FORBIDDEN, "bad-1", id="operator-command"),
    pytest.param(_msg(type="intruder", cell=[1, 1], state="on"), ErrorCode.FORBIDDEN, "bad-1",
                 id="world-report"),
    pytest.param(_msg(type="finished", action_id="0.0.3"), ErrorCode.UNKNOWN_ACTION, "bad-1",
                 id="finish-never-dispatched"),
    pytest.param(_msg(type="finished", action_id="0.0.0"), ErrorCode.REJECTED, "bad-1",
                 id="finish-before-start"),
    # strict input: no coercion, limits in bytes, depth and number length before parsing
    pytest.param(_msg(type="hello", robot_id="0"), ErrorCode.INVALID, "bad-1",
                 id="robot-id-as-string"),
    pytest.param(json.dumps({"v": 1, "msg_id": "bad-1", "seq": True, "type": "state",
                             "robot_id": 0}), ErrorCode.INVALID, "bad-1", id="seq-as-bool"),
    pytest.param(_msg(type="ack", action_id="0.0.0", v=True), ErrorCode.UNSUPPORTED_VERSION,
                 "bad-1", id="version-as-bool"),
    pytest.param(_msg(type="state", robot_id=0, pad="é" * (MAX_MESSAGE_BYTES // 2 + 1)),
                 ErrorCode.TOO_LARGE, None, id="oversized-in-bytes-not-chars"),
    pytest.param("[" * 100_000, ErrorCode.TOO_LARGE, None, id="deeply-nested"),
    pytest.param(_msg(type="state", robot_id=0).replace(": 0", ": " + "9" * 5000),
                 ErrorCode.TOO_LARGE, None, id="5000-digit-integer"),
    pytest.param(b'{"v": 1}', ErrorCode.MALFORMED, None, id="binary-frame"),
]


@pytest.mark.parametrize(("raw", "code", "ref"), BAD_INPUTS)
async def test_bad_input_gets_its_code_and_changes_nothing(raw: str | bytes, code: ErrorCode,
                                                           ref: str | None) -> None:
    async with started_fleet() as fleet:
        before = fingerprint(fleet.gw)
        await fleet.bad.link.send(raw)
        err = await fleet.bad.error_for(ref)
        assert err.code is code, err.detail
        assert fingerprint(fleet.gw) == before
        assert fleet.gw.metrics.value("fleetgate_protocol_errors_total", code=code.value) == 1
        # the others carry on meanwhile, and robot 0 (still connected) completes its part
        worker = asyncio.create_task(fleet.bad.run(backlog=[fleet.first]))
        soc, makespan = await asyncio.wait_for(fleet.gw.wait_done(), 10)
        worker.cancel()
        assert [len(r.finished) for r in fleet.others] == [3, 2]
        assert len(fleet.bad.finished) == 5
        assert soc > 0 and makespan > 0


async def test_duplicate_finish_is_applied_once() -> None:
    async with started_fleet() as fleet:
        bad, gw = fleet.bad, fleet.gw
        await bad.send(Started, action_id="0.0.0")
        await bad.send(Finished, action_id="0.0.0")
        nxt = await bad.expect(Action)
        assert nxt.action_id == "0.0.1"
        before = fingerprint(gw)
        finished_before = gw.metrics.value("fleetgate_actions_finished_total")
        ref = await bad.send(Finished, action_id="0.0.0")
        err = await bad.error_for(ref)
        assert err.code is ErrorCode.DUPLICATE
        assert fingerprint(gw) == before
        assert gw.metrics.value("fleetgate_actions_finished_total") == finished_before
        ref = await bad.send(Started, action_id="0.0.1")
        await bad.send(Started, action_id="0.0.1")
        assert (await bad.error_for(f"r0-{int(ref.split('-')[1]) + 1}")).code is ErrorCode.DUPLICATE
        # no second dispatch of 0.0.1 was sent
        assert [m.action_id for m in bad.inbox if isinstance(m, Action)] == ["0.0.0", "0.0.1"]


@pytest.mark.parametrize(("token", "status"), [(None, 401), ("wrong-token", 403),
                                               ("demo-robot-x", 403)])
async def test_handshake_rejects_missing_or_wrong_token(token: str | None,
                                                        status: int) -> None:
    async with virtual_gateway() as (_, ws_connect):
        with pytest.raises(InvalidStatus) as exc:
            await ws_connect(token)
        assert exc.value.response.status_code == status


async def test_token_in_query_string_is_accepted() -> None:
    async with virtual_gateway() as (_, ws_connect):
        robot = TestRobot(await ws_connect(None, "?token=demo-robot-4"), 4)
        welcome = await robot.hello()
        assert welcome.robot_id == 4


async def test_repeated_abuse_closes_the_connection() -> None:
    async with started_fleet() as fleet:
        limit = fleet.gw.config.max_errors
        for _ in range(limit):
            await fleet.bad.send_raw("{not json")
        with pytest.raises(ConnectionClosed) as exc:
            while True:
                await fleet.bad.recv()
        assert exc.value.rcvd is not None and exc.value.rcvd.code == 1008
        codes = [m.code for m in fleet.bad.inbox if m.type == "error"]
        assert codes == [ErrorCode.MALFORMED] * limit
        # the others finish their paths; robot 0's steps stay held (it vanished)
        await asyncio.wait_for(
            _until(lambda: [len(r.finished) for r in fleet.others] == [3, 2]), 10)
        assert fleet.gw.engine.robot(0).link is None
        assert "0.0.0" in fleet.gw.engine.robot(0).held
        assert fleet.gw.status == "running"


async def test_frame_over_the_hard_limit_closes_with_1009() -> None:
    async with started_fleet() as fleet:
        await fleet.bad.send_raw(_msg(type="state", robot_id=0, pad="x" * (300 * 1024)))
        with pytest.raises(ConnectionClosed) as exc:
            while True:
                await fleet.bad.recv()
        assert exc.value.rcvd is not None and exc.value.rcvd.code == 1009


async def test_operator_and_world_may_not_send_robot_messages() -> None:
    async with virtual_gateway() as (_, ws_connect):
        op = Peer(await ws_connect("demo-operator"), "op")
        ref = await op.send(Hello, robot_id=0)
        assert (await op.error_for(ref)).code is ErrorCode.FORBIDDEN
        world = Peer(await ws_connect("demo-world"), "w")
        ref = await world.send(Start)
        assert (await world.error_for(ref)).code is ErrorCode.FORBIDDEN


async def test_reports_before_hello_are_refused() -> None:
    async with virtual_gateway() as (_, ws_connect):
        robot = TestRobot(await ws_connect("demo-robot-0"), 0)
        ref = await robot.send(Finished, action_id="0.0.0")
        assert (await robot.error_for(ref)).code is ErrorCode.BAD_STATE


async def _until(predicate: Any) -> None:
    while not predicate():
        await asyncio.sleep(0.01)


async def test_flooding_is_rate_limited() -> None:
    # burst of 5 messages, then 1 per second: of 12 sent at once, at least 6 are refused
    async with virtual_gateway(rate_per_s=1.0, rate_burst=5.0, max_errors=100) as (_, connect):
        robot = TestRobot(await connect("demo-robot-0"), 0)
        for _ in range(12):
            await robot.send(State, robot_id=0)
        async with asyncio.timeout(5):
            while sum(1 for m in robot.inbox if isinstance(m, Error)) < 6:
                await robot.recv()
        codes = {m.code for m in robot.inbox if isinstance(m, Error)}
        assert codes == {ErrorCode.RATE_LIMITED}


async def test_second_hello_on_one_connection_counts_once() -> None:
    async with started_fleet() as fleet:
        await fleet.bad.hello()
        await fleet.bad.hello()
        assert fleet.gw.metrics.value("fleetgate_connected_robots") == 3
        assert fleet.gw.engine.connected_robots() == 3
