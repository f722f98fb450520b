"""The per-turn batcher: what is added in one turn of the loop is released once, in order,
only after the adding task yields."""

import asyncio

import pytest

from gateway.server.per_turn import PerTurn


async def test_one_release_per_turn_after_the_adder_yields() -> None:
    released: list[list[int]] = []
    turn: PerTurn[int] = PerTurn(released.append)
    for i in range(3):
        turn.add(i)
    assert released == []  # nothing leaves before the adding task yields
    await asyncio.sleep(0)
    assert released == [[0, 1, 2]]
    turn.add(3)
    await asyncio.sleep(0)
    await asyncio.sleep(0)
    assert released == [[0, 1, 2], [3]]


async def test_a_flush_releases_at_once_and_nothing_again_at_the_turn() -> None:
    released: list[list[int]] = []
    turn: PerTurn[int] = PerTurn(released.append)
    turn.flush()
    assert released == []  # nothing added: nothing released
    turn.add(0)
    turn.add(1)
    turn.flush()
    assert released == [[0, 1]]
    turn.add(2)  # after a flush, the next item is released at its own turn again
    await asyncio.sleep(0)
    await asyncio.sleep(0)
    assert released == [[0, 1], [2]]


@pytest.mark.looptime
async def test_an_interval_makes_one_release_per_interval_at_most() -> None:
    """With an interval: an item after a quiet spell goes at the next turn; items added
    sooner after a release wait together until the interval since it has passed."""
    loop = asyncio.get_running_loop()
    released: list[tuple[float, list[int]]] = []
    turn: PerTurn[int] = PerTurn(lambda items: released.append((loop.time(), items)), 0.005)
    t0 = loop.time()
    turn.add(0)
    await asyncio.sleep(0)
    assert released == [(t0, [0])]  # after a quiet spell: at once
    await asyncio.sleep(0.001)
    turn.add(1)
    await asyncio.sleep(0.002)
    turn.add(2)
    await asyncio.sleep(0.0019)
    assert len(released) == 1  # 4.9 ms after the first release: still waiting
    await asyncio.sleep(0.0001)
    await asyncio.sleep(0)
    assert released[1] == (pytest.approx(t0 + 0.005), [1, 2])
    await asyncio.sleep(0.010)
    turn.add(3)
    await asyncio.sleep(0)
    assert released[2] == (pytest.approx(t0 + 0.015), [3])  # quiet again: at once
