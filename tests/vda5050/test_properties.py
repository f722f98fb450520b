"""Property tests of order sequencing and stitching: for any path, any split of it into
releases at any times, with pauses and lost order messages, the master's orders are
well-formed, every update stitches onto the previous base's decision point with the next
``orderUpdateId``, the simulated vehicle (which checks figure 8 on its own) rejects none, and
every action is reported started then finished exactly once, in order."""

from __future__ import annotations

import json
from typing import Any

from hypothesis import given, settings
from hypothesis import strategies as st

from protocol.vda5050.models import Order
from sim_clients.vda_vehicle import order_problem
from tests.vda5050.loop import Loop, Step, actions_of
from tests.vda5050.schemas import SCHEMA_DIR, assert_valid

MOVES = {0: (1, 0), 1: (0, 1), 2: (-1, 0), 3: (0, -1)}


@st.composite
def paths(draw: st.DrawFn) -> list[Step]:
    """A turning-model path on a 10 x 10 grid: forward, turn left or right, or wait."""
    path = [(draw(st.integers(0, 9)), draw(st.integers(0, 9)), draw(st.integers(0, 3)))]
    for choice in draw(st.lists(st.sampled_from("FFFLRW"), min_size=1, max_size=16)):
        x, y, h = path[-1]
        dx, dy = MOVES[h]
        if choice == "F" and 0 <= x + dx < 10 and 0 <= y + dy < 10:
            path.append((x + dx, y + dy, h))
        elif choice in "LR":
            path.append((x, y, (h + (1 if choice == "R" else 3)) % 4))
        else:
            path.append((x, y, h))
    return path


def _check_sequencing(orders: list[dict[str, Any]]) -> None:
    last_base: dict[str, dict[str, Any]] = {}
    next_update: dict[str, int] = {}
    for data in orders:
        order = Order.model_validate(data)
        assert order_problem(order) is None, order_problem(order)
        oid, uid = data["orderId"], data["orderUpdateId"]
        if uid < next_update.get(oid, 0):
            continue  # a resend of a message already checked
        assert uid == next_update.get(oid, 0), (oid, uid)
        next_update[oid] = uid + 1
        nodes = data["nodes"]
        if uid == 0:
            assert nodes[0]["sequenceId"] == 0
        else:
            assert nodes[0] == last_base[oid], "an update stitches on the decision point"
        base = [n for n in nodes if n["released"]]
        last_base[oid] = base[-1]


@settings(deadline=None)  # one example simulates a whole run
@given(path=paths(), cuts=st.lists(st.integers(1, 4), min_size=1, max_size=8),
       gaps=st.lists(st.floats(0.0, 2.5), min_size=8, max_size=8),
       pause_at=st.none() | st.integers(0, 7), drop=st.sets(st.integers(0, 12), max_size=3),
       version=st.sampled_from(["2.0.0", "2.1.0"]), horizon=st.booleans())
def test_releases_in_any_chunks(path: list[Step], cuts: list[int], gaps: list[float],
                                pause_at: int | None, drop: set[int], version: str,
                                horizon: bool) -> None:
    loop = Loop(version, path[0], drop=drop)  # type: ignore[arg-type]
    actions = actions_of(path)
    if horizon:
        loop.master.set_plan(actions)
    t, i = 0.0, 0
    for k, size in enumerate([*cuts, len(actions)]):
        if i >= len(actions):
            break
        if k == pause_at:
            loop.master.pause(loop.now)
        loop.master.release(actions[i:i + size], loop.now)
        i += size
        t += gaps[k % len(gaps)]
        loop.run(t)
        if k == pause_at:
            loop.master.resume(loop.now)
    loop.run(t + 2.0 * len(actions) + 5)
    assert not loop.vehicle.errors, loop.vehicle.errors
    for a in actions:
        assert loop.kinds(a.action_id) == ["started", "finished"], a.action_id
    done = [r.action_id for r in loop.reports if r.kind == "finished"]
    assert done == [a.action_id for a in actions]
    assert (*loop.vehicle.cell, ) == path[-1][:2]
    _check_sequencing([json.loads(p) for topic, p in loop.traffic if topic == "order"])
    if (SCHEMA_DIR / version).is_dir():
        for topic, payload in loop.traffic:
            assert_valid(version, topic, payload)
