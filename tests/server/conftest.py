"""Fixtures: a real gateway on 127.0.0.1 (ephemeral port) and websocket clients for it.

A test marked ``pytest.mark.looptime`` runs on a looptime loop: a gateway it starts itself
with a ``VirtualClock`` runs in virtual time over the same real websockets, so the test does
not depend on the machine's load. Fixtures run in real time (looptime makes only the test's
own time virtual): the fixtures' gateways are real-time ones."""

from __future__ import annotations

from collections.abc import AsyncIterator, Awaitable, Callable
from typing import Any

import pytest
from websockets.asyncio.client import ClientConnection, connect

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


@pytest.fixture
async def gateway() -> AsyncIterator[Gateway]:
    """A started gateway listening on 127.0.0.1 (port in ``gateway.port``)."""
    async with Gateway(make_config()) as gw:
        await gw.listen()
        yield gw


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


@pytest.fixture
def ws_connect(gateway: Gateway) -> Connect:
    """:func:`connector` for the ``gateway`` fixture."""
    return connector(gateway)
