"""One conformance suite, run over both transports (in-memory and websocket on 127.0.0.1):
the same gateway behaviour whichever way the messages travel (DESIGN section 1, driver 2)."""

from __future__ import annotations

import asyncio
import contextlib
import json
import socket
from collections.abc import AsyncIterator, Awaitable, Callable
from dataclasses import dataclass
from typing import Any

import pytest
from websockets.exceptions import ConnectionClosed, InvalidStatus

from gateway.server.clock import VirtualClock
from gateway.server.gateway import Gateway
from gateway.server.wire.auth import AuthError
from protocol import ErrorCode, GetSnapshot, LoadPlan, Ok, SetThreshold
from tests.server.conftest import LAB_PATHS, connector, make_config
from tests.server.robots import ClientLink, Peer, TestRobot

pytestmark = pytest.mark.looptime  # virtual time over both transports


@dataclass
class Transport:
    """A gateway plus a way to open client connections to it over one transport."""

    name: str
    gw: Gateway
    open: Callable[[str | None], Awaitable[ClientLink]]
    open_reluctant: Callable[[str], Awaitable[ClientLink]]
    """A client that buffers as little as it can (it will not read)."""

    async def handshake_status(self, token: str | None) -> int:
        """The HTTP-like status a refused handshake gets (401/403)."""
        try:
            await self.open(token)
        except InvalidStatus as exc:
            return exc.response.status_code
        except AuthError as exc:
            return exc.status
        raise AssertionError("handshake was accepted")


@contextlib.asynccontextmanager
async def _transport(name: str, **config: Any) -> AsyncIterator[Transport]:
    """A gateway on the test's virtual time (``config`` overrides :func:`make_config`) and
    its transport ``name``."""
    async with Gateway(make_config(**config), clock=VirtualClock()) as gw:
        if name == "memory":
            async def open_memory(token: str | None) -> ClientLink:
                return await gw.connect(token or "")
            yield Transport(name, gw, open_memory, open_memory)
        else:
            await gw.listen()
            ws = connector(gw)

            async def open_ws(token: str | None) -> ClientLink:
                return await ws(token)

            async def open_small(token: str) -> ClientLink:
                sock = socket.socket()
                sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
                sock.setblocking(False)
                await asyncio.get_running_loop().sock_connect(sock, ("127.0.0.1", gw.port))
                return await ws(token, sock=sock, max_queue=1)
            yield Transport(name, gw, open_ws, open_small)


TRANSPORTS = ["memory", "websocket"]
"""Each test runs once per transport, in virtual time (none is about the real clock)."""


@pytest.mark.parametrize("name", TRANSPORTS)
async def test_hello_gets_welcome_for_the_bound_robot(name: str) -> None:
    async with _transport(name) as transport:
        robot = TestRobot(await transport.open("demo-robot-7"), 7)
        welcome = await robot.hello()
        assert welcome.robot_id == 7 and welcome.resend == []
        assert transport.gw.engine.connected_robots() == 1


@pytest.mark.parametrize("name", TRANSPORTS)
async def test_handshake_auth(name: str) -> None:
    async with _transport(name) as transport:
        assert await transport.handshake_status(None) == 401
        assert await transport.handshake_status("nobody") == 403


@pytest.mark.parametrize("name", TRANSPORTS)
async def test_order_is_preserved(name: str) -> None:
    async with _transport(name) as transport:
        op = Peer(await transport.open("demo-operator"), "op")
        refs = [await op.send(SetThreshold, threshold_ms=float(i)) for i in range(100)]
        got: list[str] = []
        async with asyncio.timeout(10):
            while len(got) < len(refs):
                msg = await op.recv()
                if isinstance(msg, Ok):
                    got.append(msg.ref)
        assert got == refs
        assert transport.gw.engine.threshold_ms == 99.0


@pytest.mark.parametrize("name", TRANSPORTS)
async def test_client_close_is_seen_by_the_gateway(name: str) -> None:
    async with _transport(name) as transport:
        robot = TestRobot(await transport.open("demo-robot-1"), 1)
        await robot.hello()
        await robot.link.close()
        async with asyncio.timeout(5):
            while transport.gw.engine.connected_robots():
                await asyncio.sleep(0.01)
        assert transport.gw.engine.robot(1).link is None


@pytest.mark.parametrize("name", TRANSPORTS)
async def test_gateway_close_after_abuse_flushes_errors_first(name: str) -> None:
    async with _transport(name) as transport:
        peer = Peer(await transport.open("demo-robot-2"), "r2")
        limit = transport.gw.config.max_errors
        for _ in range(limit):
            await peer.send_raw("[]")
        with pytest.raises(ConnectionClosed) as exc:
            async with asyncio.timeout(5):
                while True:
                    await peer.recv()
        assert [getattr(m, "code", None) for m in peer.inbox] == [ErrorCode.MALFORMED] * limit
        assert exc.value.rcvd is not None and exc.value.rcvd.code == 1008


@pytest.mark.parametrize("name", TRANSPORTS)
async def test_frame_over_the_hard_limit_closes_1009(name: str) -> None:
    async with _transport(name) as transport:
        peer = Peer(await transport.open("demo-robot-3"), "r3")
        with pytest.raises(ConnectionClosed) as exc:
            await peer.send_raw(json.dumps({"pad": "x" * 300_000}))
            async with asyncio.timeout(5):
                await peer.recv()
        assert exc.value.rcvd is not None and exc.value.rcvd.code == 1009


@pytest.mark.parametrize("name", TRANSPORTS)
async def test_a_slow_client_never_stalls_the_others(name: str) -> None:
    async with _transport(name, send_queue=8) as t:
        await t.gw.command(LoadPlan(msg_id="l", seq=0, map="lab", paths=LAB_PATHS))
        slow = Peer(await t.open_reluctant("demo-operator"), "slow")  # never reads
        fast = Peer(await t.open("demo-operator"), "fast")
        for _ in range(900):
            await slow.send(GetSnapshot)
        async with asyncio.timeout(10):
            for i in range(20):
                ref = await fast.send(SetThreshold, threshold_ms=float(i))
                while not isinstance(msg := await fast.recv(), Ok) or msg.ref != ref:
                    pass
            while len(t.gw.engine.feed.operators) != 1:  # the slow one was dropped
                await asyncio.sleep(0.01)
        with pytest.raises(ConnectionClosed):
            async with asyncio.timeout(10):
                while True:
                    await slow.recv()
