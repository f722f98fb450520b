"""The sans-I/O master control against the simulated vehicle in virtual time: orders and
updates, reports for the executor, cancel, pause, rejection, lost messages, connection; every
message on the wire validates against the official schema of its version."""

from __future__ import annotations

import json

import pytest

from protocol.vda5050.master import LinkState, Report, VehicleMaster
from protocol.vda5050.models import VERSIONS, Connection, ErrorReference, VdaError, VdaVersion
from sim_clients.world import INTRUDER, World
from tests.vda5050.loop import Loop, actions_of
from tests.vda5050.schemas import SCHEMA_DIR, assert_valid, needs_schemas

# east 2 cells, turn left (north), north 1 cell, wait: 5 actions
PATH = [(0, 5, 0), (1, 5, 0), (2, 5, 0), (2, 5, 3), (2, 4, 3), (2, 4, 3)]


def _orders(loop: Loop) -> list[dict[str, object]]:
    return [json.loads(p) for t, p in loop.traffic if t == "order"]


@pytest.mark.parametrize("version", VERSIONS)
def test_base_extended_by_updates_and_every_action_reported_in_order(version: VdaVersion) -> None:
    loop = Loop(version, PATH[0])
    actions = actions_of(PATH)
    loop.master.set_plan(actions)
    loop.master.release(actions[:2], loop.now)
    loop.run(1.5)
    assert [r.kind for r in loop.reports] == ["started", "finished", "started"]
    loop.master.release(actions[2:4], loop.now)
    loop.run(3.2)
    loop.master.release(actions[4:], loop.now)
    loop.run(10)
    for a in actions:
        assert loop.kinds(a.action_id) == ["started", "finished"], a.action_id
    assert [r.action_id for r in loop.reports if r.kind == "finished"] == [
        a.action_id for a in actions]
    orders = _orders(loop)
    assert [o["orderUpdateId"] for o in orders] == [0, 1, 2]
    assert len({o["orderId"] for o in orders}) == 1
    first, second, third = orders
    # base of order 0: start node + 2 released actions; the horizon holds the other 3
    assert [n["released"] for n in first["nodes"]] == [True] * 3 + [False] * 3
    assert [n["sequenceId"] for n in first["nodes"]] == [0, 2, 4, 6, 8, 10]
    # an update starts at the decision point (node seq 4), resends no earlier base node
    assert second["nodes"][0]["sequenceId"] == 4 and second["nodes"][0]["released"]
    assert second["nodes"][0] == first["nodes"][2]
    assert [n["sequenceId"] for n in third["nodes"]] == [8, 10]
    # the turn keeps the cell and changes theta: east 0 -> north pi/2
    turn = second["nodes"][1]
    assert turn["nodeId"] == "n2_5" and turn["nodePosition"]["theta"] == pytest.approx(1.5708,
                                                                                       abs=1e-4)
    assert loop.vehicle.cell == (2, 4) and not loop.vehicle.errors
    # 5 actions of 1 s each, with the vehicle never waiting for a release: 5 s
    assert loop.vehicle.last_node_seq == 10


@needs_schemas
@pytest.mark.parametrize("version", VERSIONS)
def test_all_traffic_validates(version: VdaVersion) -> None:
    loop = Loop(version, PATH[0])
    actions = actions_of(PATH)
    loop.master.set_plan(actions)
    loop.master.release(actions[:3], loop.now)
    loop.master.pause(loop.now)
    loop.run(2)
    loop.master.resume(loop.now)
    loop.master.request_state(loop.now)
    loop.master.cancel([actions[2].action_id], loop.now)
    loop.run(6)
    loop.master.release(actions[3:], loop.now)
    loop.run(12)
    topics = {t for t, _ in loop.traffic}
    assert {"order", "instantActions", "state", "connection"} <= topics
    for topic, payload in loop.traffic:
        assert_valid(version, topic, payload)


def test_pause_holds_the_vehicle_and_resume_continues() -> None:
    loop = Loop("2.1.0", PATH[0])
    actions = actions_of(PATH)
    loop.master.pause(loop.now)
    loop.master.release(actions, loop.now)
    loop.run(3)
    assert loop.reports == [] and loop.vehicle.cell == (0, 5) and loop.vehicle.paused
    loop.master.resume(loop.now)
    loop.run(9)
    assert loop.kinds(actions[-1].action_id) == ["started", "finished"]


def test_cancel_order_then_new_order_from_the_last_node() -> None:
    loop = Loop("2.1.0", PATH[0])
    actions = actions_of(PATH)
    loop.master.release(actions[:4], loop.now)
    loop.run(0.5)  # action 0 is running: it completes, 1..3 are cancelled
    loop.master.cancel([a.action_id for a in actions[1:4]], loop.now)
    loop.run(3)
    assert loop.kinds(actions[0].action_id) == ["started", "finished"]
    for a in actions[1:4]:
        assert loop.kinds(a.action_id) == ["cancelled"]
    assert loop.vehicle.cell == (1, 5) and not loop.vehicle.held.nodes
    sent = [json.loads(p) for t, p in loop.traffic if t == "instantActions"]
    assert sent[-1]["actions"][0]["actionType"] == "cancelOrder"
    # a replan: plan 1 starts where the vehicle stands, as a new order
    new = actions_of([(1, 5, 0), (2, 5, 0)], plan=1)
    loop.master.release(new, loop.now)
    loop.run(5)
    assert loop.kinds(new[0].action_id) == ["started", "finished"]
    orders = _orders(loop)
    assert orders[-1]["orderId"] != orders[0]["orderId"] and orders[-1]["orderUpdateId"] == 0
    assert orders[-1]["nodes"][0]["nodeId"] == "n1_5" and not loop.vehicle.errors


def test_cancel_when_the_vehicle_finished_first() -> None:
    loop = Loop("2.0.0", PATH[0])
    actions = actions_of(PATH[:3])
    loop.master.release(actions, loop.now)
    loop.run(5)  # both done; the cancel comes late: noOrderToCancel, nothing is cancelled
    loop.master.cancel([actions[1].action_id], loop.now)
    loop.run(6)
    assert [r.kind for r in loop.reports] == ["started", "finished"] * 2


def test_lost_order_update_is_resent() -> None:
    loop = Loop("2.1.0", PATH[0], drop={1})  # the first update is lost (QoS 0)
    actions = actions_of(PATH)
    loop.master.release(actions[:1], loop.now)
    loop.master.release(actions[1:], loop.now)
    loop.run(10)
    assert all(loop.kinds(a.action_id) == ["started", "finished"] for a in actions)
    assert [o["orderUpdateId"] for o in _orders(loop)] == [0, 1, 1]
    # a resent message is a new message: headerId counts every one sent (section 6.4)
    assert [o["headerId"] for o in _orders(loop)] == [0, 1, 2]


def test_rejected_order_is_refused() -> None:
    loop = Loop("2.1.0", (4, 4, 0))  # the vehicle is not where the order starts
    actions = actions_of(PATH)
    loop.master.release(actions[:2], loop.now)
    loop.run(2)
    assert [(r.kind, r.action_id) for r in loop.reports] == [
        ("refused", actions[0].action_id), ("refused", actions[1].action_id)]
    assert "noRouteError" in loop.reports[0].detail
    assert loop.vehicle.errors[0].error_type == "noRouteError"


def test_blocked_while_the_next_cell_is_taken() -> None:
    loop = Loop("2.1.0", PATH[0])
    world = World()
    world.occupy((1, 5), INTRUDER, 0.0)
    loop.vehicle.world = world
    world.occupy((0, 5), 0, 0.0)
    actions = actions_of(PATH[:3])
    loop.master.release(actions, loop.now)
    loop.run(2)
    assert [r.kind for r in loop.reports] == ["blocked"] and loop.vehicle.cell == (0, 5)
    world.release((1, 5), INTRUDER)
    loop.run(5)
    assert loop.kinds(actions[0].action_id) == ["blocked", "unblocked", "started", "finished"]
    assert world.collisions == [] and world.holders((2, 5)) == (0,)


def test_connection_is_the_link_state() -> None:
    loop = Loop("2.1.0", PATH[0])
    assert loop.links == [] or loop.links[-1].online
    loop.pump()
    assert loop.links == [LinkState(True, "ONLINE")]
    will = loop.vehicle.connect(loop.now)[0].message
    assert isinstance(will, Connection)
    loop.master.receive_connection(will)
    assert loop.master.drain() == [LinkState(False, "CONNECTIONBROKEN")]
    assert Report("started", "x") != Report("finished", "x")


def test_cancel_while_blocked_leaves_the_vehicle_ready_for_a_new_order() -> None:
    loop = Loop("2.1.0", PATH[0])
    world = World()
    loop.vehicle.world = world
    world.occupy((0, 5), 0, 0.0)
    world.occupy((1, 5), INTRUDER, 0.0)
    actions = actions_of(PATH[:3])
    loop.master.release(actions, loop.now)
    loop.run(1)
    loop.master.cancel([a.action_id for a in actions], loop.now)
    loop.run(2)
    assert [r.kind for r in loop.reports] == ["blocked", "cancelled", "cancelled"]
    # nothing left to re-check: the next wake-up is the periodic state, not the past
    assert loop.vehicle.next_wakeup_s() > loop.now + 20
    new = actions_of([(0, 5, 0), (0, 5, 3)], plan=1)
    loop.master.release(new, loop.now)
    loop.run(4)
    assert loop.kinds(new[0].action_id) == ["started", "finished"]


def test_a_new_plan_cancels_an_order_that_still_has_a_horizon() -> None:
    loop = Loop("2.1.0", PATH[0])
    actions = actions_of(PATH)
    loop.master.set_plan(actions)
    loop.master.release(actions[:2], loop.now)
    loop.run(4)  # the base is done; the vehicle waits at the decision point for its horizon
    assert loop.vehicle.held.nodes and not loop.vehicle.held.nodes[0].released
    new = actions_of([(2, 5, 0), (2, 5, 3)], plan=1)
    loop.master.release(new, loop.now)
    loop.run(7)
    assert loop.kinds(new[0].action_id) == ["started", "finished"]
    assert not loop.vehicle.errors
    kinds = [json.loads(p)["actions"][0]["actionType"] for t, p in loop.traffic
             if t == "instantActions"]
    assert kinds == ["cancelOrder"]


@pytest.mark.parametrize("lose_update", [False, True])
def test_a_restarted_master_takes_over_the_vehicles_order(lose_update: bool) -> None:
    loop = Loop("2.1.0", PATH[0])
    actions = actions_of(PATH)
    loop.master.set_plan(actions)
    loop.master.release(actions[:4], loop.now)
    loop.run(1.5)  # action 0 finished, action 1 running, 2 and 3 in the base
    assert loop.kinds(actions[0].action_id) == ["started", "finished"]
    # the master restarts (kill -9): a new one, same vehicle, nothing remembered but the
    # vehicle's state
    old = loop.master
    loop.master = VehicleMaster(old.topics, "2.1.0", old.nodes)
    assert loop.vehicle.drain() == []
    state = old.state
    assert state is not None
    finished, base = loop.master.adopt(state)
    assert finished == [actions[0].action_id]
    assert base == [a.action_id for a in actions[1:4]]
    # the gateway resends what it has no finish for: the base is adopted, not sent again
    rest = loop.master.adopt_actions(actions[1:])
    assert rest == actions[4:]
    loop.master.set_plan(actions)
    loop.master.release(rest, loop.now)
    if lose_update:
        loop.drop.add(loop._sent)
    loop.reports.clear()
    loop.run(10)
    for a in actions[1:]:
        assert loop.kinds(a.action_id) == ["started", "finished"], a.action_id
    assert not loop.vehicle.errors and loop.vehicle.cell == (2, 4)
    updates = [json.loads(p) for t, p in loop.traffic if t == "order"]
    assert updates[-1]["orderUpdateId"] == state.order_update_id + 1
    assert updates[-1]["nodes"][0]["sequenceId"] == 8  # the decision point: action 3's node


def test_a_finished_order_is_not_resent_to_a_vehicle_showing_another() -> None:
    loop = Loop("2.1.0", PATH[0])
    actions = actions_of(PATH[:3])
    loop.master.release(actions, loop.now)
    loop.run(3)
    assert loop.kinds(actions[-1].action_id) == ["started", "finished"]
    sent = len([t for t, _ in loop.traffic if t == "order"])
    # a new vehicle takes the serial number's place (its state shows no order at all)
    fresh = loop.vehicle.__class__(loop.vehicle.topics, "2.1.0", loop.vehicle.nodes, (0, 5))
    loop.vehicle = fresh
    loop.run(6)
    assert len([t for t, _ in loop.traffic if t == "order"]) == sent
    assert fresh.held.order_id == "" and fresh.cell == (0, 5)


@pytest.mark.parametrize("version", VERSIONS)
def test_factsheet_on_connect_and_on_request(version: VdaVersion) -> None:
    loop = Loop(version, PATH[0])
    loop.run(0.1)
    sheet = loop.master.factsheet
    assert sheet is not None and sheet.version == version
    assert sheet.supports("pick", "NODE") and sheet.supports("drop", "EDGE")
    assert sheet.supports("cancelOrder", "INSTANT") and not sheet.supports("pick", "INSTANT")
    # factsheetRequest is a 2.1.0 instant action: the vehicle publishes its factsheet again;
    # a 2.0.0 vehicle fails the unknown action
    assert sheet.supports("factsheetRequest", "INSTANT") == (version == "2.1.0")
    loop.master.request_factsheet(loop.now)
    loop.run(0.5)
    sheets = [t for t, _ in loop.traffic if t == "factsheet"]
    status = loop.vehicle.action_states["factsheetRequest-1"].action_status
    assert (len(sheets), status) == ((2, "FINISHED") if version == "2.1.0" else (1, "FAILED"))
    for topic, payload in loop.traffic:
        if (SCHEMA_DIR / version).is_dir():
            assert_valid(version, topic, payload)


def test_takeover_maps_edges_to_the_gateways_action_ids() -> None:
    # under drop_waits the wait (action 1) has no ADG vertex: the robot's actions are 0, 2, 3
    path = [(0, 5, 0), (1, 5, 0), (1, 5, 0), (2, 5, 0), (3, 5, 0)]
    actions = [a for i, a in enumerate(actions_of(path)) if i != 1]
    loop = Loop("2.1.0", path[0])
    loop.master.release(actions, loop.now)
    loop.run(1.5)  # action 0 finished, action 2 running
    old = loop.master
    state = old.state
    assert state is not None

    def steps(key: str, first: int, count: int) -> list[str | None]:
        out: list[str | None] = [a.action_id for a in actions if a.sequence >= first]
        return out[:count]

    loop.master = VehicleMaster(old.topics, "2.1.0", old.nodes, ids=steps)
    finished, base = loop.master.adopt(state)
    assert finished == [actions[0].action_id]
    assert base == [a.action_id for a in actions[1:]]  # not ".1" and ".2": no index counting
    assert loop.master.adopt_actions(actions[1:]) == []
    loop.reports.clear()
    loop.run(6)
    assert [r.kind for r in loop.reports if r.action_id == actions[-1].action_id] == [
        "started", "finished"]
    assert loop.vehicle.cell == (3, 5) and not loop.vehicle.errors


@pytest.mark.parametrize("instance", ["", "n."])
def test_a_restarted_masters_cancel_order_has_a_new_action_id(instance: str) -> None:
    # a vehicle may keep the states of finished instant actions (section 6.8 only asks that
    # actionIds be unique): a restarted master that named its cancelOrder as its predecessor
    # did would read the old one's FINISHED as its own and cancel actions the vehicle drives
    loop = Loop("2.1.0", PATH[0])
    first = actions_of(PATH[:3])
    loop.master.release(first, loop.now)
    loop.run(0.5)
    loop.master.cancel([a.action_id for a in first[1:]], loop.now)
    loop.run(2)  # the vehicle stopped at (1, 5); it lists cancelOrder-1 FINISHED
    kept = loop.vehicle.action_states["cancelOrder-1"]
    assert kept.action_status == "FINISHED"
    old = loop.master
    loop.master = VehicleMaster(old.topics, "2.1.0", old.nodes, instance=instance)
    loop.reports.clear()
    new = actions_of([(1, 5, 0), (2, 5, 0), (3, 5, 0), (4, 5, 0)], plan=1)
    loop.master.release(new, loop.now)
    loop.run(2.5)  # action 0 of the new order runs
    loop.master.cancel([a.action_id for a in new[1:]], loop.now)
    # a state published before the cancel arrived, on its way, from a vehicle that keeps
    # the states of finished instant actions
    state = loop.master.state
    assert state is not None and state.driving
    loop.master.receive_state(state.model_copy(update={
        "action_states": [*state.action_states, kept]}), loop.now)
    loop.run(6)
    assert loop.vehicle.cell == (2, 5)  # it drove action 0, then stopped
    cancelled = [r.action_id for r in loop.reports if r.kind == "cancelled"]
    assert cancelled == [a.action_id for a in new[1:]]
    if instance:
        assert loop.kinds(new[0].action_id) == ["started", "finished"]
    else:  # the old naming: the stale FINISHED ended the cancel at once, so action 0 went
        # into a new order the driving vehicle rejected: the action it drove was refused
        assert loop.kinds(new[0].action_id) == ["started", "refused"]


def _held_paused(errors: list[VdaError]) -> tuple[Loop, list[str]]:
    """A paused vehicle holding an order whose state carries ``errors``: the reports."""
    loop = Loop("2.1.0", PATH[0])
    actions = actions_of(PATH)
    loop.master.pause(loop.now)
    loop.master.release(actions, loop.now)
    loop.run(1)
    state = loop.master.state
    assert state is not None and state.order_id and not state.driving
    loop.master.receive_state(state.model_copy(update={"errors": errors}), loop.now)
    return loop, [r.kind for r in loop.master.drain() if isinstance(r, Report)]


def test_a_fatal_error_blocks_a_complaint_about_an_instant_action_does_not() -> None:
    refs = [ErrorReference(reference_key="actionId", reference_value="cancelOrder-3")]
    _, kinds = _held_paused([VdaError(error_type="noOrderToCancel", error_level="WARNING",
                                      error_references=refs)])
    assert kinds == []
    _, kinds = _held_paused([VdaError(error_type="motorFault", error_level="FATAL")])
    assert kinds == ["blocked"]
    _, kinds = _held_paused([VdaError(error_type="obstacle", error_level="WARNING")])
    assert kinds == ["blocked"]
