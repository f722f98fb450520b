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


async def test_what_a_source_held_during_the_wait_joins_the_batch_it_waited_for() -> None:
    """An ``Engine.holding`` source (the workers' channels) keeps what arrives while the
    owner task waits for its batch and queues it in the turn after the release (as a socket
    read then would): it is handled in that batch, not one ``batch_ms`` later."""
    config = GatewayConfig(port=0, log_level="WARNING", batch_ms=5.0)
    async with Gateway(config) as gw:
        loop = asyncio.get_running_loop()
        await asyncio.sleep(1.0)  # a quiet spell
        held: list[OwnerCall] = []
        holds: list[tuple[float, bool]] = []
        times: list[float] = []

        def hold(on: bool) -> None:
            holds.append((loop.time(), on))
            if not on:  # read in the next turn, after the steps already due in it
                for item in held:  # (as a selector's events follow the turn's ready handles)
                    loop.call_soon(loop.call_soon, gw.engine.queue.put_nowait, item)
                held.clear()

        def arrive() -> None:
            item = OwnerCall(lambda: times.append(loop.time()))
            if holds and holds[-1][1]:
                held.append(item)
            else:
                gw.engine.queue.put_nowait(item)

        gw.engine.holding.append(hold)
        t0 = loop.time()
        for gap in (0.0, 0.001, 0.001):
            await asyncio.sleep(gap)
            arrive()
        await asyncio.sleep(1.0)
    # the first at once; the second wakes the owner, which holds until 5 ms after the first;
    # the third, held, is handled with the second
    assert [(round(t - t0, 6), on) for t, on in holds] == [(0.001, True), (0.005, False)]
    assert [round(t - t0, 6) for t in times] == [0.0, 0.005, 0.005]
