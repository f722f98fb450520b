"""Lifelong errands over VDA 5050, master against the simulated vehicle in virtual time: an
action that brings the vehicle onto an errand cell ends on a node with a ``pick`` or ``drop``
action (blocking HARD) and is finished only when that node action is; a shift's segments
extend one order; a master restarted while a pick runs takes it over without sending it
again; every message validates against the schemas."""

from __future__ import annotations

import json
from collections.abc import Callable

import pytest

from protocol.messages import Action
from protocol.vda5050.master import Errand, ErrandFailed, VehicleMaster
from protocol.vda5050.models import VERSIONS, VdaVersion
from tests.vda5050.loop import Loop, actions_of
from tests.vda5050.schemas import assert_valid, needs_schemas

PATH = [(0, 5, 0), (1, 5, 0), (2, 5, 0), (3, 5, 0), (4, 5, 0)]
"""Four moves east: the vehicle picks after the first, drops after the last."""


def _errands(actions: list[Action]) -> Callable[[Action], list[Errand]]:
    errands = {actions[0].action_id: [Errand("pick", "pick-t7.0", "task-7")],
               actions[-1].action_id: [Errand("drop", "drop-t7.1", "task-7")]}
    return lambda action: errands.get(action.action_id, [])


def _loop(version: VdaVersion, errands: Callable[[Action], list[Errand]]) -> Loop:
    loop = Loop(version, PATH[0])
    loop.master.errand = errands
    loop.master.continuous = True
    return loop


def _finished_at(loop: Loop) -> dict[str, float]:
    return {r.action_id: t for r, t in zip(loop.reports, loop.report_times, strict=True)
            if r.kind == "finished"}


@pytest.mark.parametrize("version", VERSIONS)
def test_errand_actions_finish_with_their_pick_and_drop(version: VdaVersion) -> None:
    # segment 0 holds actions 0-1, segment 1 (another plan key) actions 2-3
    first, second = actions_of(PATH)[:2], actions_of(PATH, plan=1)[2:]
    loop = _loop(version, _errands(first + second))
    loop.master.release(first, loop.now)
    loop.run(1.5)
    loop.master.release(second, loop.now)
    loop.run(10)
    for a in first + second:
        assert loop.kinds(a.action_id) == ["started", "finished"], a.action_id
    orders = [json.loads(p) for t, p in loop.traffic if t == "order"]
    # the second segment extends the order (the vehicle was still driving it)
    assert [o["orderUpdateId"] for o in orders] == [0, 1]
    assert len({o["orderId"] for o in orders}) == 1
    pick = orders[0]["nodes"][1]["actions"]
    assert [(a["actionType"], a["blockingType"]) for a in pick] == [("pick", "HARD")]
    assert {"key": "loadId", "value": "task-7"} in pick[0]["actionParameters"]
    # the decision point is resent unchanged, pick included (section 6.6.2)
    assert orders[1]["nodes"][0] == orders[0]["nodes"][-1]
    assert [a["actionType"] for a in orders[1]["nodes"][-1]["actions"]] == ["drop"]
    # 1 s per move, 1 s per node action (the simulator's action_s): the pick holds the
    # vehicle, and its action is finished when the pick is, not on arrival
    start = 1_700_000_000.0
    done = _finished_at(loop)
    assert done[first[0].action_id] - start == pytest.approx(2.0)
    assert done[first[1].action_id] - start == pytest.approx(3.0)
    assert done[second[-1].action_id] - start == pytest.approx(6.0)
    states = loop.vehicle.action_states
    assert [states[k].action_status for k in ("pick-t7.0", "drop-t7.1")] == ["FINISHED"] * 2


def test_a_finished_order_is_followed_by_a_new_one() -> None:
    first, second = actions_of(PATH)[:2], actions_of(PATH, plan=1)[2:]
    loop = _loop("2.1.0", lambda _: [])
    loop.master.release(first, loop.now)
    loop.run(4)  # the vehicle finished the order and stands idle
    loop.master.release(second, loop.now)
    loop.run(8)
    orders = [json.loads(p) for t, p in loop.traffic if t == "order"]
    assert [o["orderUpdateId"] for o in orders] == [0, 0]
    assert orders[1]["nodes"][0]["nodeId"] == "n2_5" and not loop.vehicle.errors
    assert loop.kinds(second[-1].action_id) == ["started", "finished"]


def test_a_failed_pick_blocks_its_action_until_the_gateway_gives_it_up() -> None:
    actions = actions_of(PATH)[:2]
    loop = _loop("2.1.0", _errands(actions))
    loop.vehicle.fail_actions = {"pick"}
    loop.master.release(actions, loop.now)
    loop.run(5)
    assert loop.kinds(actions[0].action_id) == ["started", "blocked"]
    assert loop.kinds(actions[1].action_id) == []
    assert loop.failed == [ErrandFailed("pick-t7.0", actions[0].action_id)]  # said once
    # the pick is terminal (FAILED): the vehicle drove on through its base meanwhile
    assert loop.vehicle.cell == (2, 5)
    loop.master.give_up("pick-t7.0", loop.now)  # its task was cancelled: the action is done
    loop.pump()
    assert loop.kinds(actions[0].action_id) == ["started", "blocked", "unblocked", "finished"]
    assert loop.kinds(actions[1].action_id) == ["started", "finished"]
    assert loop.failed == [ErrandFailed("pick-t7.0", actions[0].action_id)]


def test_a_master_restarted_during_a_pick_does_not_pick_twice() -> None:
    actions = actions_of(PATH)
    errands = _errands(actions)
    loop = _loop("2.1.0", errands)
    loop.master.release(actions[:3], loop.now)
    loop.run(1.5)  # on the pick's node, the pick runs
    assert loop.vehicle.action_states["pick-t7.0"].action_status == "RUNNING"
    old = loop.master
    loop.master = VehicleMaster(old.topics, "2.1.0", old.nodes, continuous=True,
                                errand=errands)
    state = old.state
    assert state is not None
    finished, base = loop.master.adopt(state)
    assert finished == []  # its pick has not finished: action 0 is not
    assert base == [a.action_id for a in actions[:3]]
    rest = loop.master.adopt_actions(actions)
    assert rest == actions[3:]
    loop.master.release(rest, loop.now)
    loop.reports.clear()
    loop.run(10)
    for a in actions:
        assert loop.kinds(a.action_id)[-1] == "finished", a.action_id
    assert loop.vehicle.node_actions_run == ["pick-t7.0", "drop-t7.1"]
    assert not loop.vehicle.errors and loop.vehicle.cell == (4, 5)


@needs_schemas
@pytest.mark.parametrize("version", VERSIONS)
def test_errand_traffic_validates(version: VdaVersion) -> None:
    actions = actions_of(PATH)
    loop = _loop(version, _errands(actions))
    loop.master.release(actions[:2], loop.now)
    loop.run(2.5)
    loop.master.release(actions[2:], loop.now)
    loop.run(9)
    assert any(b'"pick"' in p for t, p in loop.traffic if t == "order")
    for topic, payload in loop.traffic:
        assert_valid(version, topic, payload)


def test_an_errand_the_vehicle_stands_on_is_done_before_it_drives_off() -> None:
    actions = actions_of(PATH)[:2]
    late = Errand("pick", "pick-t8.0-depart", "task-8", on_edge=True)
    loop = _loop("2.1.0", lambda a: [late] if a is actions[1] else [])
    loop.master.release(actions, loop.now)
    loop.run(5)
    orders = [json.loads(p) for t, p in loop.traffic if t == "order"]
    assert [a["actionId"] for a in orders[0]["edges"][1]["actions"]] == ["pick-t8.0-depart"]
    assert orders[0]["nodes"][2]["actions"] == []
    done = _finished_at(loop)
    start = 1_700_000_000.0
    # action 0 ends on arrival; action 1 waits 1 s for the pick at its start, then drives
    assert done[actions[0].action_id] - start == pytest.approx(1.0)
    assert done[actions[1].action_id] - start == pytest.approx(3.0)
    assert loop.vehicle.node_actions_run == ["pick-t8.0-depart"]
    # a master that releases the action again (after a restart) does not send the pick twice
    master = VehicleMaster(loop.master.topics, "2.1.0", loop.master.nodes,
                           errand=lambda a: [late])
    master.state = loop.master.state
    master.release(actions[1:], loop.now)
    order = next(e.message for e in master.drain() if hasattr(e, "message"))
    assert order.edges[0].actions == []  # type: ignore[attr-defined]


def test_a_failed_errand_before_driving_off_blocks_until_given_up() -> None:
    actions = actions_of(PATH)[:2]
    late = Errand("pick", "pick-t8.0-depart", "task-8", on_edge=True)
    loop = _loop("2.1.0", lambda a: [late] if a is actions[1] else [])
    loop.vehicle.fail_actions = {"pick"}
    loop.master.release(actions, loop.now)
    loop.run(5)
    # the vehicle drove on after the failed pick, but the action waits for the gateway
    assert loop.vehicle.cell == (2, 5)
    assert loop.kinds(actions[0].action_id) == ["started", "finished"]
    assert loop.kinds(actions[1].action_id) == ["blocked"]
    assert loop.failed == [ErrandFailed("pick-t8.0-depart", actions[1].action_id)]
    loop.master.give_up("pick-t8.0-depart", loop.now)
    loop.pump()
    assert loop.kinds(actions[1].action_id) == ["blocked", "unblocked", "started", "finished"]


def test_a_full_order_is_followed_by_a_new_one_not_extended() -> None:
    # a vehicle keeps every action state of its order until a new order comes (section
    # 6.10.6): in a shift, an order takes at most max_steps actions, the next ones go out
    # as a new order from where the vehicle stands once it has done the full one
    actions = actions_of(PATH)
    loop = _loop("2.1.0", _errands(actions))
    loop.master.max_steps = 3
    for action in actions:  # one at a time, while the vehicle drives (lookahead)
        loop.master.release([action], loop.now)
    loop.run(10)
    for a in actions:
        assert loop.kinds(a.action_id) == ["started", "finished"], a.action_id
    orders = [json.loads(p) for t, p in loop.traffic if t == "order"]
    assert [(o["orderId"], o["orderUpdateId"]) for o in orders] == [
        ("0.0.0", 0), ("0.0.0", 1), ("0.0.0", 2), ("0.0.3", 0)]
    assert orders[-1]["nodes"][0]["nodeId"] == "n3_5"  # where the vehicle stood
    assert not loop.vehicle.errors and loop.vehicle.cell == (4, 5)
    assert set(loop.vehicle.action_states) == {"drop-t7.1"}  # the first order's are gone
