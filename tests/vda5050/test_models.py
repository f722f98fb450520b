"""VDA 5050 message models: what fleetgate writes validates against the official schemas of
both versions, and what vehicles write is read (unknown fields ignored, 2.0.0 spellings)."""

from __future__ import annotations

import json

import pytest

from protocol.vda5050.models import (
    VERSIONS,
    Action,
    Connection,
    Edge,
    InstantActions,
    Node,
    Order,
    State,
    dump,
    parse,
)
from protocol.vda5050.nodes import NodeMap
from protocol.vda5050.topics import VehicleTopics, split_topic, timestamp
from tests.vda5050.schemas import assert_valid, needs_schemas, schema_errors

HEADER = {"header_id": 3, "timestamp": timestamp(1_700_000_000.123), "manufacturer": "acme",
          "serial_number": "sn-1"}


def _order(version: str) -> Order:
    nodes = NodeMap(cell_m=0.5, map_id="floor1")
    return Order(**HEADER, version=version, order_id="r1.0.2.0", order_update_id=0,
                 nodes=[Node(node_id="n0_0", sequence_id=0, released=True,
                             node_position=nodes.position((0, 0), "E")),
                        Node(node_id="n1_0", sequence_id=2, released=False,
                             node_position=nodes.position((1, 0), "E"),
                             actions=[Action(action_type="pick", action_id="p1",
                                             blocking_type="HARD")])],
                 edges=[Edge(edge_id="e0_0_1_0", sequence_id=1, released=False,
                             start_node_id="n0_0", end_node_id="n1_0")])


@needs_schemas
@pytest.mark.parametrize("version", VERSIONS)
def test_order_and_instant_actions_validate(version: str) -> None:
    assert_valid(version, "order", dump(_order(version)))
    msg = InstantActions(**HEADER, version=version, actions=[
        Action(action_type="startPause", action_id="a1", blocking_type="HARD")])
    assert_valid(version, "instantActions", dump(msg))


@needs_schemas
def test_schema_oracle_rejects_what_the_standard_forbids() -> None:
    data = json.loads(dump(_order("2.1.0")))
    del data["nodes"][0]["sequenceId"]
    assert schema_errors("2.1.0", "order", data)
    bad_time = json.loads(dump(_order("2.1.0")))
    bad_time["timestamp"] = "yesterday"
    assert schema_errors("2.1.0", "order", bad_time)
    # 2.0.0's instantActions schema names the action type actionName: actionType alone fails it
    data = json.loads(dump(InstantActions(**HEADER, version="2.1.0", actions=[
        Action(action_type="startPause", action_id="a1", blocking_type="HARD")])))
    assert schema_errors("2.0.0", "instantActions", data)
    assert not schema_errors("2.1.0", "instantActions", data)


def test_version_spellings() -> None:
    ia20 = json.loads(dump(InstantActions(**HEADER, version="2.0.0", actions=[
        Action(action_type="stopPause", action_id="a1", blocking_type="HARD")])))
    assert ia20["actions"][0]["actionName"] == ia20["actions"][0]["actionType"] == "stopPause"
    read = parse("instantActions", json.dumps({**ia20, "actions": [
        {"actionName": "stopPause", "actionId": "x", "blockingType": "NONE"}]}))
    assert isinstance(read, InstantActions) and read.actions[0].action_type == "stopPause"


def test_unknown_fields_are_ignored_and_bad_messages_raise() -> None:
    state = {"headerId": 1, "timestamp": "2026-01-01T00:00:00.00Z", "version": "2.1.0",
             "manufacturer": "m", "serialNumber": "s", "orderId": "", "orderUpdateId": 0,
             "lastNodeId": "", "lastNodeSequenceId": 0, "nodeStates": [], "edgeStates": [],
             "driving": False, "actionStates": [], "operatingMode": "AUTOMATIC", "errors": [],
             "batteryState": {"batteryCharge": 50, "charging": False, "vendorX": 1},
             "safetyState": {"eStop": "NONE", "fieldViolation": False}, "vendorField": [1]}
    msg = parse("state", json.dumps(state))
    assert isinstance(msg, State) and msg.battery_state.battery_charge == 50
    with pytest.raises(ValueError):
        parse("state", json.dumps({**state, "driving": "maybe"}))
    with pytest.raises(ValueError):
        parse("state", b"{not json")
    with pytest.raises(ValueError):
        parse("responses", b"{}")
    conn = parse("connection", dump(Connection(**HEADER, version="2.0.0",
                                                connection_state="CONNECTIONBROKEN")))
    assert isinstance(conn, Connection) and conn.connection_state == "CONNECTIONBROKEN"


def test_topics_and_timestamps() -> None:
    topics = VehicleTopics("uagv", "v2", "KIT", "0001")
    assert topics.topic("order") == "uagv/v2/KIT/0001/order"
    assert split_topic(topics.topic("state")) == ("uagv", "v2", "KIT", "0001", "state")
    assert timestamp(1_492_256_403.129) == "2017-04-15T11:40:03.12Z"
    for bad in ("a/b", "x$", "+", ""):
        with pytest.raises(ValueError):
            VehicleTopics("uagv", "v2", "KIT", bad)
    with pytest.raises(ValueError):
        VehicleTopics("uagv", "v2", "K#T", "1")


def test_node_positions() -> None:
    nodes = NodeMap(cell_m=0.5, map_id="m", origin_y=2.0)
    pos = nodes.position((2, 0), "N")
    assert (pos.x, pos.y, pos.theta) == (1.25, 1.75, pytest.approx(1.5707963267948966))
    assert nodes.position((0, 3), None).theta is None
    assert nodes.cell_of(1.25, 1.75) == (2, 0) and nodes.cell_of(0.1, 0.1) == (0, 3)
    assert nodes.position((1, 1), "W").theta == pytest.approx(3.141592653589793)
    with pytest.raises(ValueError):
        NodeMap(cell_m=0.0, map_id="m")
