"""The owner task's batches (``batch_ms``): under a steady stream of items it handles what
arrived within ``batch_ms`` of its last batch together (one commit, one write to each worker);
an item after a quiet spell is handled at once; virtual time never waits."""

from __future__ import annotations

import asyncio

import pytest

from gateway.server.clock import VirtualClock
from gateway.server.config import GatewayConfig
from gateway.server.gateway import Gateway
from gateway.server.items import OwnerCall

pytestmark = pytest.mark.looptime  # the loop's time is virtual: exact instants


async def handled_at(gw: Gateway, gaps_s: list[float]) -> list[float]:
    """Queue an item, then one more after each gap; the loop times they were handled at."""
    loop = asyncio.get_running_loop()
    times: list[float] = []
    for gap in [0.0, *gaps_s]:
        await asyncio.sleep(gap)
        gw.engine.queue.put_nowait(OwnerCall(lambda: times.append(loop.time())))
    await asyncio.sleep(1.0)
    return times


async def test_a_steady_stream_is_handled_once_per_batch_ms() -> None:
    config = GatewayConfig(port=0, log_level="WARNING", batch_ms=5.0)
    async with Gateway(config) as gw:
        await asyncio.sleep(1.0)  # a quiet spell
        t0 = asyncio.get_running_loop().time()
        times = await handled_at(gw, [0.001, 0.001, 0.001, 0.010])
    # the first at once; the next three, 1-3 ms later, together 5 ms after it; the last,
    # 13 ms after the first (8 ms after the last batch began), at once
    assert [round(t - t0, 6) for t in times] == [0.0, 0.005, 0.005, 0.005, 0.013]


async def test_without_batch_ms_each_item_is_handled_when_it_comes() -> None:
    config = GatewayConfig(port=0, log_level="WARNING", batch_ms=0.0)
    async with Gateway(config) as gw:
        t0 = asyncio.get_running_loop().time()
        times = await handled_at(gw, [0.001, 0.001])
    assert [round(t - t0, 6) for t in times] == [0.0, 0.001, 0.002]


async def test_virtual_time_never_waits_for_a_batch() -> None:
    config = GatewayConfig(port=0, log_level="WARNING", batch_ms=5.0)
    async with Gateway(config, clock=VirtualClock()) as gw:
        t0 = asyncio.get_running_loop().time()
        times = await handled_at(gw, [0.001, 0.001])
    assert [round(t - t0, 6) for t in times] == [0.0, 0.001, 0.002]
