"""Transport defences against a real gateway on 127.0.0.1: malformed upgrade requests get
400/401/403 (never 500), a failed handshake leaves nothing behind, hello and idle timeouts, the
error budget decays, no exception escapes a connection handler, the world's reports are
checked, and no page an unauthenticated client can fetch holds the operator token. The
in-process gateways run in virtual time (their timeouts read the loop's clock), so the
timeouts are checked exactly at any load."""

from __future__ import annotations

import asyncio
import gc
import json
import logging
from typing import Any

import pytest
from websockets.exceptions import ConnectionClosed

from gateway.server.clock import VirtualClock
from gateway.server.gateway import Gateway
from protocol import CloseCode, ErrorCode, Hello, IntruderReport, LoadPlan, State
from tests.server.conftest import LAB_PATHS, connector, make_config
from tests.server.robots import Peer, TestRobot

UPGRADE = ("GET /ws HTTP/1.1\r\nHost: 127.0.0.1\r\nUpgrade: websocket\r\n"
           "Connection: Upgrade\r\nSec-WebSocket-Version: 13\r\n")
KEY = "Sec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\n"


async def raw_request(port: int, head: bytes) -> int:
    """Send a raw HTTP request head; the response's status code."""
    reader, writer = await asyncio.open_connection("127.0.0.1", port)
    writer.write(head + b"\r\n")
    await writer.drain()
    line = await reader.readline()
    writer.close()
    return int(line.split()[1])


@pytest.mark.parametrize(("head", "status"), [
    pytest.param(UPGRADE + KEY + "Authorization: Bearer demo-robot-\u00b2\r\n", 400,
                 id="non-ascii-token-in-header"),
    pytest.param(UPGRADE.replace("/ws", "/ws?token=demo-robot-%C2%B2") + KEY, 400,
                 id="non-ascii-token-in-query"),
    pytest.param(UPGRADE + KEY + "Authorization: Bearer demo-robot-0\r\n"
                 "Authorization: Bearer demo-robot-1\r\n", 400, id="two-authorization-headers"),
    pytest.param(UPGRADE + KEY + "Upgrade: websocket\r\nAuthorization: Bearer demo-robot-0\r\n",
                 400, id="two-upgrade-headers"),
    pytest.param(UPGRADE.replace("/ws", "/ws?token=a&token=b") + KEY, 400,
                 id="two-query-tokens"),
    pytest.param(UPGRADE + KEY + "Authorization: Basic abc\r\n", 401, id="basic-auth"),
    pytest.param(UPGRADE + KEY + "Authorization: Bearer nope\r\n", 403, id="unknown-token"),
    pytest.param(UPGRADE + KEY + "Authorization: Bearer demo-operator\r\n"
                 "Origin: http://evil.example\r\n", 403, id="foreign-origin"),
    pytest.param(UPGRADE + KEY + "Authorization: Bearer demo-operator\r\n"
                 "Origin: http://a\r\nOrigin: http://b\r\n", 400, id="two-origins"),
    pytest.param(UPGRADE + KEY + "Cookie: fleetgate_session=forged\r\n", 401,
                 id="forged-login-cookie"),
])
@pytest.mark.looptime  # virtual time over real sockets
async def test_bad_upgrade_requests_get_4xx(head: str, status: int,
                                            caplog: pytest.LogCaptureFixture) -> None:
    async with Gateway(make_config(), clock=VirtualClock()) as gw:
        port = await gw.listen()
        assert await raw_request(port, head.encode("utf-8")) == status
    assert not [r for r in caplog.records if r.levelno >= logging.ERROR]


@pytest.mark.looptime  # virtual time over real sockets
async def test_failed_handshakes_leave_nothing_behind() -> None:
    async with Gateway(make_config(), clock=VirtualClock()) as gw:
        port = await gw.listen()
        # a valid token, but no Sec-WebSocket-Key: websockets refuses after our check passed
        head = (UPGRADE + "Authorization: Bearer demo-robot-0\r\n").encode()
        statuses = await asyncio.gather(*(raw_request(port, head) for _ in range(200)))
        assert set(statuses) == {400}
        await asyncio.sleep(0.1)
        gc.collect()
        assert gw.pending_handshakes == 0
        assert gw.sessions == set()


async def _closed_with(robot: Peer) -> int:
    with pytest.raises(ConnectionClosed) as exc:
        async with asyncio.timeout(5):
            while True:
                await robot.recv()
    assert exc.value.rcvd is not None
    return exc.value.rcvd.code


@pytest.mark.looptime  # virtual time over real sockets
async def test_a_robot_that_never_says_hello_is_closed() -> None:
    async with Gateway(make_config(hello_timeout_s=0.2), clock=VirtualClock()) as gw:
        await gw.listen()
        silent = TestRobot(await connector(gw)("demo-robot-0"), 0)
        await silent.send(State, robot_id=0)  # not a hello: the clock keeps running
        assert await _closed_with(silent) == CloseCode.HELLO_TIMEOUT
        await asyncio.sleep(0.05)
        assert gw.sessions == set()
        # an operator has no hello and no such timeout
        op = Peer(await connector(gw)("demo-operator"), "op")
        await asyncio.sleep(0.4)
        assert len(gw.sessions) == 1 and op.link is not None


@pytest.mark.looptime  # virtual time over real sockets
async def test_an_idle_robot_is_closed_and_a_talking_one_is_not() -> None:
    async with Gateway(make_config(idle_timeout_s=0.3), clock=VirtualClock()) as gw:
        await gw.listen()
        idle = TestRobot(await connector(gw)("demo-robot-0"), 0)
        talking = TestRobot(await connector(gw)("demo-robot-1"), 1)
        await idle.hello()
        await talking.hello()
        for _ in range(6):
            await talking.send(State, robot_id=1)
            await asyncio.sleep(0.1)
        assert await _closed_with(idle) == CloseCode.IDLE_TIMEOUT
        assert gw.engine.connected_robots() == 1


@pytest.mark.looptime  # virtual time over real sockets
async def test_the_idle_deadline_counts_from_the_last_message() -> None:
    """One deadline per connection, moved by every message: a robot that talks for more than
    twice the idle time stays, and once silent it is closed no sooner than the idle time after
    its last message."""
    async with Gateway(make_config(idle_timeout_s=0.3), clock=VirtualClock()) as gw:
        await gw.listen()
        robot = TestRobot(await connector(gw)("demo-robot-0"), 0)
        await robot.hello()
        loop = asyncio.get_running_loop()
        for _ in range(8):
            await robot.send(State, robot_id=0)
            await asyncio.sleep(0.1)
        assert gw.engine.connected_robots() == 1
        await robot.send(State, robot_id=0)
        last = loop.time()
        assert await _closed_with(robot) == CloseCode.IDLE_TIMEOUT
        assert loop.time() - last >= 0.3
        await asyncio.sleep(0.05)
        assert gw._sessions == set()


@pytest.mark.looptime  # virtual time over real sockets
async def test_the_error_budget_decays() -> None:
    async with Gateway(make_config(max_errors=3, error_decay_s=0.1), clock=VirtualClock()) as gw:
        await gw.listen()
        robot = TestRobot(await connector(gw)("demo-robot-0"), 0)
        for _ in range(10):  # 2 errors per 0.25 s: never 3 within the budget
            await robot.send_raw("{bad")
            await robot.send_raw("{bad")
            await asyncio.sleep(0.25)
        assert (await robot.error_for(None)).code is ErrorCode.MALFORMED
        for _ in range(3):
            await robot.send_raw("{bad")
        assert await _closed_with(robot) == CloseCode.POLICY
        assert sum(1 for m in robot.inbox if m.type == "error") == 23


@pytest.mark.looptime  # virtual time over real sockets
async def test_no_exception_escapes_a_handler(monkeypatch: pytest.MonkeyPatch,
                                              caplog: pytest.LogCaptureFixture) -> None:
    async with Gateway(make_config(), clock=VirtualClock()) as gw:
        await gw.listen()
        ok = TestRobot(await connector(gw)("demo-robot-1"), 1)
        await ok.hello()
        admit = gw._admit

        def explode(session: Any, raw: str | bytes) -> Any:
            if raw == "boom":
                raise RuntimeError("a bug")
            return admit(session, raw)

        monkeypatch.setattr(gw, "_admit", explode)
        victim = TestRobot(await connector(gw)("demo-robot-0"), 0)
        await victim.send_raw("boom")
        assert await _closed_with(victim) == CloseCode.INTERNAL
        failures = [r for r in caplog.records if r.getMessage() == "connection handler failed"]
        assert len(failures) == 1 and failures[0].exc_info is None
        assert "RuntimeError('a bug')" in failures[0].__dict__["error"]
        assert gw.metrics.value("fleetgate_handler_failures_total") == 1
        await ok.send(State, robot_id=1)  # the others carry on
        await ok.hello()
        assert gw.engine.connected_robots() == 1


@pytest.mark.looptime  # virtual time over real sockets
async def test_world_reports_are_checked_before_the_trace(tmp_path: Any) -> None:
    trace = tmp_path / "trace.jsonl"
    async with Gateway(make_config(trace=trace), clock=VirtualClock()) as gw:
        await gw.listen()
        assert (await gw.command(LoadPlan(msg_id="l", seq=0, map="lab", paths=LAB_PATHS)))[0] \
            is None
        world = Peer(await connector(gw)("demo-world"), "w")
        grid = gw.engine.problem.instance.grid  # type: ignore[union-attr]
        wall = next((x, y) for y in range(grid.height) for x in range(grid.width)
                    if not grid.is_free((x, y)))
        ref = await world.send(IntruderReport, cell=wall, state="on")
        assert (await world.error_for(ref)).code is ErrorCode.REJECTED
        ref = await world.send(IntruderReport, cell=(200, 200), state="on")
        assert (await world.error_for(ref)).code is ErrorCode.REJECTED
        ref = await world.send(IntruderReport, cell=(0, 1), state="off")
        assert (await world.error_for(ref)).code is ErrorCode.DUPLICATE
        await world.send(IntruderReport, cell=(0, 1), state="on")
        ref = await world.send(IntruderReport, cell=(0, 1), state="on")
        assert (await world.error_for(ref)).code is ErrorCode.DUPLICATE
        assert gw.engine.feed.intruders == {(0, 1)}
        ref = await world.send(Hello, robot_id=0)
        assert (await world.error_for(ref)).code is ErrorCode.FORBIDDEN
    records = [json.loads(line) for line in trace.read_text().splitlines()] \
        if trace.exists() else []
    assert [(r["cell"], r["state"]) for r in records if r["type"] == "intruder"] in (
        [], [([0, 1], "on")])


def test_a_log_storm_becomes_a_few_lines_and_a_count() -> None:
    from gateway.server.logs import RateLimit

    limit = RateLimit(burst=3, window_s=0.2)
    logger = logging.getLogger("fleetgate.test.storm")
    records = [logger.makeRecord(logger.name, logging.ERROR, __file__, 1,
                                 "socket.accept() out of system resource", (), None)
               for _ in range(1000)]
    assert sum(map(limit.filter, records)) == 3
    import time

    time.sleep(0.25)
    late = logger.makeRecord(logger.name, logging.ERROR, __file__, 1,
                             "socket.accept() out of system resource", (), None)
    assert limit.filter(late) and late.__dict__["suppressed"] == 997


def test_out_of_file_descriptors_the_gateway_stays_quiet_and_recovers() -> None:
    """A gateway whose hard limit is 100 open files gets 150 idle TCP connections: a few log
    lines (not one per failed accept), and it serves again once they are gone."""
    import re
    import resource
    import socket
    import subprocess
    import sys
    import time
    import urllib.request
    from pathlib import Path

    def low_limit() -> None:
        resource.setrlimit(resource.RLIMIT_NOFILE, (100, 100))

    fleetgate = Path(sys.executable).parent / "fleetgate"
    proc = subprocess.Popen([str(fleetgate), "serve", "--port", "0", "--log-level", "WARNING"],
                            stderr=subprocess.PIPE, text=True, preexec_fn=low_limit)
    try:
        assert proc.stderr is not None
        port = int(re.findall(r":(\d+)/ws", proc.stderr.readline())[0])
        idle = []
        for _ in range(150):
            try:
                idle.append(socket.create_connection(("127.0.0.1", port), timeout=2))
            except OSError:
                break
        time.sleep(3)
        for s in idle:
            s.close()
        opener = urllib.request.build_opener(urllib.request.ProxyHandler({}))
        deadline = time.monotonic() + 10
        while True:
            try:
                with opener.open(f"http://127.0.0.1:{port}/healthz", timeout=2) as resp:
                    assert resp.status == 200
                break
            except OSError:
                assert time.monotonic() < deadline, "the gateway did not recover"
                time.sleep(0.2)
    finally:
        proc.terminate()
        _, err = proc.communicate(timeout=10)
    lines = err.splitlines()
    assert len(lines) <= 25, lines[:30]
    assert not any("Traceback" in line for line in lines)
