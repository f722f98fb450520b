"""Helpers: a real gateway on 127.0.0.1 (ephemeral port) and websocket clients for it.

A test marked ``pytest.mark.looptime`` runs on a looptime loop: a gateway it starts itself
with a ``VirtualClock`` (:func:`virtual_gateway`) runs in virtual time over the same real
websockets, so the test does not depend on the machine's load. Fixtures would run in real time
(looptime makes only the test's own time virtual): a test starts its gateway itself."""

from __future__ import annotations

import contextlib
from collections.abc import AsyncIterator, Awaitable, Callable
from typing import Any

from websockets.asyncio.client import ClientConnection, connect

from gateway.server.clock import VirtualClock
from gateway.server.config import GatewayConfig
from gateway.server.gateway import Gateway

LAB_PATHS = [
    # hand-made 1-robust plan on the shipped lab map (rows 0-1 are free; see lab.map)
    [(0, 0), (1, 0), (2, 0), (3, 0), (4, 0), (5, 0)],
    [(0, 1), (1, 1), (2, 1), (3, 1)],
    [(13, 0), (12, 0), (11, 0)],
]
"""Robot k moves right along its row (2: left); no two paths meet, so it is 1-robust."""

Connect = Callable[..., Awaitable[ClientConnection]]


def make_config(**overrides: Any) -> GatewayConfig:
    """A loopback test configuration (ephemeral port, demo tokens, short close timeout).

    Classic dispatch (``dispatch_lookahead=0``) unless overridden: these tests script exact
    message sequences and counts; lookahead has its own tests (test_lookahead.py)."""
    return GatewayConfig(**{"port": 0, "close_timeout_s": 1.0, "dispatch_lookahead": 0,
                            **overrides})


def ws_url(gw: Gateway, query: str = "") -> str:
    """The websocket URL of a listening gateway."""
    return f"ws://127.0.0.1:{gw.port}/ws{query}"


def connector(gw: Gateway) -> Connect:
    """Opens websockets to a listening gateway with a bearer token (no proxy, no
    compression); ``query`` is appended to the URL (e.g. ``?token=...``)."""

    async def _connect(token: str | None, query: str = "", **kw: Any) -> ClientConnection:
        headers = {"Authorization": f"Bearer {token}"} if token else {}
        return await connect(ws_url(gw, query), additional_headers=headers, proxy=None,
                             compression=None, **kw)

    return _connect


@contextlib.asynccontextmanager
async def virtual_gateway(**config: Any) -> AsyncIterator[tuple[Gateway, Connect]]:
    """On the test's virtual time (in a test marked ``pytest.mark.looptime``): a listening
    gateway (``config`` overrides :func:`make_config`) and its websocket connector."""
    async with Gateway(make_config(**config), clock=VirtualClock()) as gw:
        await gw.listen()
        yield gw, connector(gw)
