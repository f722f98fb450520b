"""Pydantic models of the VDA 5050 messages fleetgate sends and receives (versions 2.0.0 and
2.1.0, topic major version ``v2``).

Field names are the standard's camelCase on the wire (``model_dump(by_alias=True)`` through
:func:`dump`); in Python they are snake_case. Received messages may carry fields this module
does not model (the standard's schemas allow additional properties, and vehicles add their
own): they are ignored, never an error. Produced messages carry only what the schemas define.

Where the two versions differ on the wire, :func:`dump` writes what the configured version's
schema wants:

- 2.0.0's ``instantActions`` schema names an action's type ``actionName`` and the array
  ``actions``; the 2.0 text (and vehicles written from it, e.g. vda-5050-lib) say
  ``actionType`` and ``instantActions``. For 2.0.0 every instant action carries both keys and
  the message both arrays (the schema allows additional properties); one read with either
  spelling is accepted.
- 2.0.0 spells a node position's deviation ``allowedDeviationXy``, 2.1.0 ``allowedDeviationXY``.
"""

from __future__ import annotations

import json
from typing import Annotated, Any, Literal

from pydantic import AliasChoices, BaseModel, ConfigDict, Field
from pydantic.alias_generators import to_camel

VdaVersion = Literal["2.0.0", "2.1.0"]
"""The protocol versions fleetgate speaks (the ``version`` field of every message)."""

VERSIONS: tuple[VdaVersion, ...] = ("2.0.0", "2.1.0")

UInt32 = Annotated[int, Field(ge=0, le=2**32 - 1)]
BlockingType = Literal["NONE", "SOFT", "HARD"]
ActionStatus = Literal["WAITING", "INITIALIZING", "RUNNING", "PAUSED", "FINISHED", "FAILED"]
ConnectionState = Literal["ONLINE", "OFFLINE", "CONNECTIONBROKEN"]
ErrorLevel = Literal["WARNING", "FATAL"]
OperatingMode = Literal["AUTOMATIC", "SEMIAUTOMATIC", "MANUAL", "SERVICE", "TEACHIN"]
EStop = Literal["AUTOACK", "MANUAL", "REMOTE", "NONE"]


class VdaModel(BaseModel):
    """Base of every VDA 5050 structure: camelCase on the wire, unknown fields ignored."""

    model_config = ConfigDict(alias_generator=to_camel, populate_by_name=True, extra="ignore",
                              frozen=True)


class Header(VdaModel):
    """The protocol header every message starts with (section 6.4)."""

    header_id: UInt32
    timestamp: str
    version: str
    manufacturer: str
    serial_number: str


class ActionParameter(VdaModel):
    """One ``key``/``value`` parameter of an action."""

    key: str
    value: Any


class Action(VdaModel):
    """An action on a node, an edge or in ``instantActions``."""

    action_type: str = Field(validation_alias=AliasChoices("actionType", "actionName",
                                                           "action_type"))
    action_id: str
    blocking_type: BlockingType
    action_description: str | None = None
    action_parameters: list[ActionParameter] | None = None


class NodePosition(VdaModel):
    """Where a node is on map ``map_id`` (metres; ``theta`` in radians, [-pi, pi])."""

    x: float
    y: float
    map_id: str
    theta: float | None = None
    allowed_deviation_xy: float | None = Field(
        default=None, validation_alias=AliasChoices("allowedDeviationXY", "allowedDeviationXy",
                                                    "allowed_deviation_xy"))
    allowed_deviation_theta: float | None = None


class Node(VdaModel):
    """A node of an order: ``released`` nodes are the base, the others the horizon."""

    node_id: str
    sequence_id: UInt32
    released: bool
    actions: list[Action] = Field(default_factory=list)
    node_position: NodePosition | None = None
    node_description: str | None = None


class Edge(VdaModel):
    """An edge of an order, from ``start_node_id`` to ``end_node_id``."""

    edge_id: str
    sequence_id: UInt32
    released: bool
    start_node_id: str
    end_node_id: str
    actions: list[Action] = Field(default_factory=list)
    edge_description: str | None = None
    max_speed: float | None = None
    orientation: float | None = None
    rotation_allowed: bool | None = None
    length: float | None = None


class Order(Header):
    """Topic ``order`` (master control -> vehicle): a new order or an order update."""

    order_id: str
    order_update_id: UInt32
    nodes: list[Node]
    edges: list[Edge]
    zone_set_id: str | None = None


class InstantActions(Header):
    """Topic ``instantActions`` (master control -> vehicle); read from ``actions`` or 2.0's
    ``instantActions``."""

    actions: list[Action] = Field(validation_alias=AliasChoices("actions", "instantActions"))


class NodeState(VdaModel):
    """A node the vehicle still has to traverse."""

    node_id: str
    sequence_id: UInt32
    released: bool
    node_description: str | None = None


class EdgeState(VdaModel):
    """An edge the vehicle still has to traverse."""

    edge_id: str
    sequence_id: UInt32
    released: bool
    edge_description: str | None = None


class AgvPosition(VdaModel):
    """The vehicle's pose on a map."""

    x: float
    y: float
    theta: float
    map_id: str
    position_initialized: bool
    localization_score: float | None = None
    deviation_range: float | None = None


class Velocity(VdaModel):
    """The vehicle's velocity in its own frame."""

    vx: float | None = None
    vy: float | None = None
    omega: float | None = None


class ActionState(VdaModel):
    """Where one action of the order or of ``instantActions`` is in its life cycle."""

    action_id: str
    action_status: ActionStatus
    action_type: str | None = None
    action_description: str | None = None
    result_description: str | None = None


class BatteryState(VdaModel):
    """The battery (charge in percent)."""

    battery_charge: float
    charging: bool
    battery_voltage: float | None = None
    battery_health: float | None = None
    reach: float | None = None


class ErrorReference(VdaModel):
    """What an error or information entry refers to, e.g. ``orderId`` and its value."""

    reference_key: str
    reference_value: str


class VdaError(VdaModel):
    """An active error or warning of the vehicle."""

    error_type: str
    error_level: ErrorLevel
    error_references: list[ErrorReference] | None = None
    error_description: str | None = None
    error_hint: str | None = None


class Info(VdaModel):
    """Information for visualisation or debugging (never for logic)."""

    info_type: str
    info_level: Literal["DEBUG", "INFO"]
    info_references: list[ErrorReference] | None = None
    info_description: str | None = None


class SafetyState(VdaModel):
    """E-stop and protective field."""

    e_stop: EStop = "NONE"
    field_violation: bool = False


class Load(VdaModel):
    """A load the vehicle carries (only the identifying fields are modelled)."""

    load_id: str | None = None
    load_type: str | None = None
    load_position: str | None = None


class State(Header):
    """Topic ``state`` (vehicle -> master control)."""

    order_id: str
    order_update_id: UInt32
    last_node_id: str
    last_node_sequence_id: UInt32
    node_states: list[NodeState]
    edge_states: list[EdgeState]
    driving: bool
    action_states: list[ActionState]
    battery_state: BatteryState
    operating_mode: OperatingMode
    errors: list[VdaError]
    safety_state: SafetyState
    paused: bool | None = None
    new_base_request: bool | None = None
    distance_since_last_node: float | None = None
    agv_position: AgvPosition | None = None
    velocity: Velocity | None = None
    loads: list[Load] | None = None
    information: list[Info] | None = None
    zone_set_id: str | None = None


class Connection(Header):
    """Topic ``connection`` (vehicle, or the broker's last will -> master control)."""

    connection_state: ConnectionState


class Visualization(Header):
    """Topic ``visualization`` (vehicle -> visualisation systems): the pose, more often."""

    agv_position: AgvPosition | None = None
    velocity: Velocity | None = None


class AgvAction(VdaModel):
    """An action type a vehicle supports and where (``INSTANT``, ``NODE``, ``EDGE``)."""

    action_type: str
    action_scopes: list[Literal["INSTANT", "NODE", "EDGE"]]
    action_description: str | None = None


class ProtocolFeatures(VdaModel):
    """The factsheet's ``protocolFeatures``: the optional fields and the actions supported."""

    optional_parameters: list[dict[str, Any]]
    agv_actions: list[AgvAction]


class Factsheet(Header):
    """Topic ``factsheet`` (vehicle -> master control, section 6.15): what the vehicle is and
    supports. The parts the master reads are modelled (``protocolFeatures``); the others are
    kept as JSON objects. ``headerId`` and ``timestamp`` are optional in the schema but every
    message of section 6.4 has them (fleetgate's vehicles send them)."""

    type_specification: dict[str, Any]
    physical_parameters: dict[str, Any]
    protocol_limits: dict[str, Any]
    protocol_features: ProtocolFeatures
    agv_geometry: dict[str, Any]
    load_specification: dict[str, Any]
    vehicle_config: dict[str, Any] | None = None

    def supports(self, action_type: str, scope: Literal["INSTANT", "NODE", "EDGE"]) -> bool:
        """Whether the vehicle lists ``action_type`` with ``scope``."""
        return any(a.action_type == action_type and scope in a.action_scopes
                   for a in self.protocol_features.agv_actions)


Message = Order | InstantActions | State | Connection | Visualization | Factsheet

TOPIC_MODELS: dict[str, type[Header]] = {
    "order": Order, "instantActions": InstantActions, "state": State,
    "connection": Connection, "visualization": Visualization, "factsheet": Factsheet,
}
"""The model of each topic's messages."""


def to_wire(message: Header) -> dict[str, Any]:
    """The JSON object of ``message`` for its own ``version`` (see the module docstring)."""
    data: dict[str, Any] = message.model_dump(by_alias=True, exclude_none=True)
    if message.version.startswith("2.0."):
        if isinstance(message, InstantActions):
            for action in data["actions"]:
                action["actionName"] = action["actionType"]
            data["instantActions"] = data["actions"]
        if isinstance(message, Order):
            for node in data["nodes"]:
                position = node.get("nodePosition", {})
                if "allowedDeviationXY" in position:
                    position["allowedDeviationXy"] = position.pop("allowedDeviationXY")
    return data


def dump(message: Header) -> bytes:
    """``message`` as the UTF-8 JSON payload of an MQTT publish."""
    return json.dumps(to_wire(message), separators=(",", ":")).encode()


def parse(topic: str, payload: bytes | str) -> Header:
    """The message of ``topic`` (its last level, e.g. ``"state"``) in ``payload``.

    Raises ValueError (pydantic's ValidationError is one) for malformed JSON, an unknown topic
    or a message that does not validate.
    """
    model = TOPIC_MODELS.get(topic)
    if model is None:
        raise ValueError(f"unknown VDA 5050 topic {topic!r}")
    return model.model_validate_json(payload)
