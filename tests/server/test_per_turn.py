"""The per-turn batcher: what is added in one turn of the loop is released once, in order,
only after the adding task yields."""

import asyncio

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
