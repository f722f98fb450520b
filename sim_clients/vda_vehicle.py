"""A simulated VDA 5050 vehicle (2.0.0 or 2.1.0), written from the specification, as a sans-I/O
state machine: :class:`VdaVehicle` takes the payloads of its ``order`` and ``instantActions``
topics and the time, and hands back the messages to publish. :mod:`sim_clients.vda_fleet` runs
many of them over MQTT in one process.

What it does (section numbers of the 2.1.0 text):

* orders are accepted as in figure 8 (6.6.2): a malformed order is a ``validationError``
  warning; a new ``orderId`` while the vehicle still has nodes to traverse, or whose first node
  is not where it stands, is rejected (``orderUpdateError``, ``noRouteError``); an update with
  a lower ``orderUpdateId`` is an ``orderUpdateError``, the same one is ignored, a higher one
  is stitched onto the decision point (while the order runs) or onto the last traversed node
  (once the base is done); the horizon is replaced. Rejection warnings carry ``orderId`` and
  ``orderUpdateId`` references and stay until an order is accepted (6.6.4);
* it drives released edges only, one after the other: ``move_s`` per edge that moves one cell
  or turns 90 degrees (a 180-degree turn takes twice that), ``wait_s`` for an edge that does
  neither (a wait of the plan), plus an optional per-edge delay. On a shared
  :class:`sim_clients.world.World` (as robot ``who``) it holds its cell, and while it moves
  into the next one that one too; before it enters a cell it checks that the cell is free;
  while it is not, it stands with its protective field violated and re-checks every
  ``recheck_s``;
* a node is traversed when the vehicle arrives (6.10.2): its state leaves ``nodeStates``, the
  edge before it ``edgeStates``, ``lastNodeId`` / ``lastNodeSequenceId`` become its own, and its
  actions (e.g. ``pick`` / ``drop``) run for ``action_s`` each, blocking the next edge;
* instant actions (6.8): ``startPause`` / ``stopPause`` (a running edge completes, no new edge
  starts while paused), ``cancelOrder`` (stops at the next node; ``noOrderToCancel`` when it has
  no order), ``stateRequest``, ``factsheetRequest`` (2.1.0: the factsheet is published again);
  other types FAIL;
* the factsheet (6.15) is published (retained) when the vehicle connects;
* a state is published on every event of 6.10 and at least every ``state_period_s``;
* a vehicle created without a start position (``fleetgate sim --vda5050``, which does not
  know the gateway's plan) reports ``positionInitialized`` false and takes the first node of
  its first order as its position: a simulator's convenience, like the websocket robots that
  the gateway's welcome places.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field

from protocol.vda5050.master import Publish
from protocol.vda5050.models import Action as VdaAction
from protocol.vda5050.models import (
    ActionState,
    AgvAction,
    AgvPosition,
    BatteryState,
    Connection,
    ConnectionState,
    Edge,
    EdgeState,
    ErrorReference,
    Factsheet,
    InstantActions,
    Node,
    NodeState,
    Order,
    ProtocolFeatures,
    SafetyState,
    State,
    VdaError,
    VdaVersion,
    parse,
)
from protocol.vda5050.nodes import NodeMap
from protocol.vda5050.topics import Headers, VehicleTopics
from sim_clients.world import World

Cell = tuple[int, int]


@dataclass(slots=True)
class _Drive:
    """The edge being traversed and when the vehicle arrives at its end node."""

    edge: Edge
    node: Node
    until_s: float


@dataclass(slots=True)
class _Held:
    """The order the vehicle holds."""

    order_id: str = ""
    update_id: int = 0
    nodes: list[Node] = field(default_factory=list)
    edges: list[Edge] = field(default_factory=list)


def order_problem(order: Order) -> str | None:
    """Why ``order`` is not a well-formed order (6.6.1), or None."""
    nodes, edges = order.nodes, order.edges
    if not nodes:
        return "an order has at least one node"
    if len(edges) != len(nodes) - 1:
        return f"{len(nodes)} nodes need {len(nodes) - 1} edges, got {len(edges)}"
    for i, edge in enumerate(edges):
        before, after = nodes[i], nodes[i + 1]
        if (edge.start_node_id, edge.end_node_id) != (before.node_id, after.node_id):
            return f"edge {edge.edge_id} does not join {before.node_id} and {after.node_id}"
        if not (before.sequence_id + 1 == edge.sequence_id == after.sequence_id - 1):
            return f"sequenceIds around edge {edge.edge_id} do not count up by one"
        if edge.released and not (before.released and after.released):
            return f"released edge {edge.edge_id} joins a node that is not released"
        if (edge.released or after.released) and not before.released:
            return f"{edge.edge_id}: a released element follows the horizon"
    if not nodes[0].released:
        return "the first node of an order must be released"
    for node in nodes:
        if node.node_position is None:
            return f"node {node.node_id} has no nodePosition (this vehicle needs one)"
    return None


class VdaVehicle:
    """One simulated vehicle (see the module docstring)."""

    def __init__(self, topics: VehicleTopics, version: VdaVersion, nodes: NodeMap,
                 start: Cell | None,
                 theta: float = 0.0, *, move_s: float = 1.0, wait_s: float = 1.0,
                 action_s: float = 1.0, recheck_s: float = 0.1, state_period_s: float = 30.0,
                 world: World | None = None, who: int = 0,
                 delay_s: Callable[[int], float] | None = None) -> None:
        self.topics = topics
        self.version = version
        self.nodes = nodes
        self.placed = start is not None
        """Whether the vehicle knows where it is (``start`` None: the first order places it)."""
        self.cell: Cell = start if start is not None else (0, 0)
        self.theta = theta
        self.move_s, self.wait_s, self.action_s = move_s, wait_s, action_s
        self.recheck_s, self.state_period_s = recheck_s, state_period_s
        self.world, self.who = world, who
        if world is not None and start is not None:
            world.occupy(start, who, 0.0)
        self.delay_s = delay_s
        self.held = _Held()
        self.last_node_id = ""
        self.last_node_seq = 0
        self.paused = False
        self.field_violation = False
        self.drive: _Drive | None = None
        self.edges_driven = 0
        self.driven: list[tuple[str, int]] = []
        """``(orderId, edge sequenceId)`` of every edge driven, in order."""
        self.action_states: dict[str, ActionState] = {}
        self.node_actions_run: list[str] = []
        """The ``actionId`` of every node action started, in order."""
        self.fail_actions: set[str] = set()
        """Node action types that FAIL here (a broken vehicle, for tests)."""
        self.errors: list[VdaError] = []
        self._busy_until = 0.0
        self._pending_actions: list[str] = []
        self._cancel: str | None = None
        self._recheck_at: float | None = None
        self._last_state_s = -math.inf
        self._header = Headers(version, topics)
        self._out: list[Publish] = []
        self._dirty = True

    # ------------------------------------------------------------------ driver API

    def connect(self, now_s: float) -> tuple[Publish, Publish]:
        """The last will (``CONNECTIONBROKEN``) to register, and the ``ONLINE`` message; the
        factsheet (retained) is queued for :meth:`drain`."""
        self._out.append(Publish("factsheet", self.factsheet(now_s)))
        return (Publish("connection", self._connection("CONNECTIONBROKEN", now_s)),
                Publish("connection", self._connection("ONLINE", now_s)))

    def factsheet(self, now_s: float) -> Factsheet:
        """This vehicle's factsheet (section 6.15): a differential-drive carrier that takes
        ``move_s`` per cell and per 90-degree turn, with the actions it implements."""
        speed = self.nodes.cell_m / self.move_s
        instant = ["startPause", "stopPause", "cancelOrder", "stateRequest"]
        if self.version != "2.0.0":
            instant.append("factsheetRequest")
        return Factsheet(
            **self._header("factsheet", now_s),
            type_specification={"seriesName": "fleetgate-sim", "agvKinematic": "DIFF",
                                "agvClass": "CARRIER", "maxLoadMass": 0.0,
                                "localizationTypes": ["GRID"],
                                "navigationTypes": ["AUTONOMOUS"]},
            physical_parameters={"speedMin": 0.0, "speedMax": speed, "accelerationMax": 1.0,
                                 "decelerationMax": 1.0, "heightMax": 0.5,
                                 "width": 0.8 * self.nodes.cell_m,
                                 "length": 0.8 * self.nodes.cell_m},
            protocol_limits={"maxStringLens": {}, "maxArrayLens": {}, "timing": {
                "minOrderInterval": 0.0, "minStateInterval": 0.0,
                "defaultStateInterval": self.state_period_s}},
            protocol_features=ProtocolFeatures(optional_parameters=[], agv_actions=[
                *(AgvAction(action_type=t, action_scopes=["INSTANT"]) for t in instant),
                *(AgvAction(action_type=t, action_scopes=["NODE", "EDGE"])
                  for t in ("pick", "drop"))]),
            agv_geometry={}, load_specification={})

    def disconnect(self, now_s: float) -> Publish:
        """The ``OFFLINE`` message to send before a graceful disconnect."""
        return Publish("connection", self._connection("OFFLINE", now_s))

    def receive(self, topic: str, payload: bytes | str, now_s: float) -> None:
        """A message on the vehicle's ``order`` or ``instantActions`` topic."""
        try:
            msg = parse(topic, payload)
        except ValueError as exc:
            self._reject("validationError", f"{topic}: {str(exc).splitlines()[0]}", [])
            return
        if isinstance(msg, Order):
            self._order(msg, now_s)
        elif isinstance(msg, InstantActions):
            for action in msg.actions:
                self._instant(action.action_type, action.action_id, now_s)
        self.step(now_s)

    def step(self, now_s: float) -> None:
        """Advance to ``now_s``: arrive, start edges, publish a state when something changed."""
        if self.drive is not None and now_s >= self.drive.until_s:
            self._arrive(self.drive, now_s)
        if self.drive is None and now_s >= self._busy_until:
            self._finish_node_actions()
            if self._cancel is not None:
                self._cancel_done()
            self._maybe_start(now_s)
        if self._dirty or now_s - self._last_state_s >= self.state_period_s:
            self._publish_state(now_s)

    def next_wakeup_s(self) -> float:
        """When :meth:`step` has something to do next."""
        times = [self._last_state_s + self.state_period_s]
        if self.drive is not None:
            times.append(self.drive.until_s)
        if self._pending_actions:
            times.append(self._busy_until)
        if self._recheck_at is not None and self.drive is None:
            times.append(self._recheck_at)
        return min(times)

    def drain(self) -> list[Publish]:
        """The messages to publish, in order (then cleared)."""
        out, self._out = self._out, []
        return out

    @property
    def target(self) -> Cell | None:
        """The cell the vehicle is driving into, if any."""
        if self.drive is None or self.drive.node.node_position is None:
            return None
        pos = self.drive.node.node_position
        return self.nodes.cell_of(pos.x, pos.y)

    # ------------------------------------------------------------------ orders

    def _executing(self) -> bool:
        return bool(self.held.nodes) or any(
            a.action_status not in ("FINISHED", "FAILED") for a in self.action_states.values())

    def _order(self, order: Order, now_s: float) -> None:
        refs = [("orderId", order.order_id), ("orderUpdateId", str(order.order_update_id))]
        problem = order_problem(order)
        if problem is not None:
            self._reject("validationError", problem, refs)
            return
        first = order.nodes[0]
        held = self.held
        if order.order_id != held.order_id:
            if not self.placed:
                self._place(first)
            if self._executing():
                self._reject("orderUpdateError", "a new order while the current one runs", refs)
            elif not self._at(first):
                self._reject("noRouteError", f"the first node {first.node_id} is not where "
                             "the vehicle stands", refs)
            else:
                self.action_states = {k: a for k, a in self.action_states.items()
                                      if a.action_status not in ("FINISHED", "FAILED")}
                self.held = _Held(order.order_id, order.order_update_id)
                self.last_node_id, self.last_node_seq = first.node_id, first.sequence_id
                self._accept(order, order.nodes[1:], order.edges, first, now_s)
            return
        if order.order_update_id < held.update_id:
            self._reject("orderUpdateError", f"orderUpdateId {order.order_update_id} is older "
                         f"than {held.update_id}", refs)
            return
        if order.order_update_id == held.update_id:
            return  # a resent message: ignored (6.6.4.3)
        base = [n for n in held.nodes if n.released]
        if base or held.edges:
            point = (base[-1].node_id, base[-1].sequence_id) if base else (
                self.last_node_id, self.last_node_seq)
        else:
            point = (self.last_node_id, self.last_node_seq)
        if (first.node_id, first.sequence_id) != point:
            self._reject("orderUpdateError", f"the update starts at {first.node_id}/"
                         f"{first.sequence_id}, not at {point[0]}/{point[1]}", refs)
            return
        held.update_id = order.order_update_id
        held.nodes = [n for n in held.nodes if n.released]
        held.edges = [e for e in held.edges if e.released]
        self._accept(order, order.nodes[1:], order.edges, None, now_s)

    def _place(self, node: Node) -> None:
        """A simulator's convenience (no real vehicle does this): a vehicle started without a
        position stands on the first node of its first order."""
        pos = node.node_position
        if pos is None:
            return
        cell = self.nodes.cell_of(pos.x, pos.y)
        if self.world is not None:
            if not self.world.is_free(cell):
                return
            self.world.occupy(cell, self.who, 0.0)
        self.cell, self.placed = cell, True
        if pos.theta is not None:
            self.theta = pos.theta

    def _at(self, node: Node) -> bool:
        pos = node.node_position
        return pos is not None and self.nodes.cell_of(pos.x, pos.y) == self.cell

    def _accept(self, order: Order, nodes: list[Node], edges: list[Edge],
                first: Node | None, now_s: float) -> None:
        self.errors = []
        self.held.nodes.extend(nodes)
        self.held.edges.extend(edges)
        for element in ([first] if first else []) + nodes + edges:
            for action in element.actions:
                self.action_states[action.action_id] = ActionState(
                    action_id=action.action_id, action_type=action.action_type,
                    action_status="WAITING")
        if first is not None:
            self._run_node_actions(first, now_s)
        self._dirty = True

    def _reject(self, kind: str, why: str, refs: list[tuple[str, str]]) -> None:
        self.errors.append(VdaError(error_type=kind, error_level="WARNING",
                                    error_description=why[:500], error_references=[
                                        ErrorReference(reference_key=k, reference_value=v)
                                        for k, v in refs]))
        self._dirty = True

    # ------------------------------------------------------------------ driving

    def _maybe_start(self, now_s: float) -> None:
        held = self.held
        if (self.paused or self._cancel is not None or not held.edges
                or not held.edges[0].released or not held.nodes[0].released):
            self._set_violation(False)
            self._recheck_at = None
            return
        edge, node = held.edges[0], held.nodes[0]
        waiting = [a for a in edge.actions
                   if self.action_states[a.action_id].action_status == "WAITING"]
        if waiting:  # HARD edge actions (pick, drop) run before the vehicle drives off
            self._run_actions(waiting, now_s)
            return
        assert node.node_position is not None
        pos = node.node_position
        cell = self.nodes.cell_of(pos.x, pos.y)
        if cell != self.cell and self.world is not None:
            if not self.world.is_free(cell):
                self._set_violation(True)
                self._recheck_at = now_s + self.recheck_s
                return
            self.world.occupy(cell, self.who, now_s * 1000)
        self._set_violation(False)
        self._recheck_at = None
        theta = self.theta if pos.theta is None else pos.theta
        turns = round(abs(math.remainder(theta - self.theta, 2 * math.pi)) / (math.pi / 2))
        duration = self.move_s * (turns + (cell != self.cell)) or self.wait_s
        if self.delay_s is not None:
            duration += self.delay_s(self.edges_driven)
        self.drive = _Drive(edge, node, now_s + duration)
        self._dirty = True

    def _set_violation(self, value: bool) -> None:
        if value != self.field_violation:
            self.field_violation = value
            self._dirty = True

    def _arrive(self, drive: _Drive, now_s: float) -> None:
        held = self.held
        held.edges.pop(0)
        held.nodes.pop(0)
        pos = drive.node.node_position
        assert pos is not None
        cell = self.nodes.cell_of(pos.x, pos.y)
        if cell != self.cell and self.world is not None:
            self.world.release(self.cell, self.who)
        self.cell = cell
        if pos.theta is not None:
            self.theta = pos.theta
        self.last_node_id, self.last_node_seq = drive.node.node_id, drive.node.sequence_id
        self.drive = None
        self.edges_driven += 1
        self.driven.append((held.order_id, drive.edge.sequence_id))
        self._dirty = True
        self._run_node_actions(drive.node, now_s)
        if self.drive is None and self._busy_until <= now_s:
            self._finish_node_actions()  # instantaneous node actions (``action_s`` 0)
            self._maybe_start(now_s)

    def _run_node_actions(self, node: Node, now_s: float) -> None:
        self._run_actions(node.actions, now_s)

    def _run_actions(self, actions: list[VdaAction], now_s: float) -> None:
        if actions:
            self._busy_until = now_s + self.action_s * len(actions)
            self._dirty = True
        for action in actions:
            self.node_actions_run.append(action.action_id)
            self.action_states[action.action_id] = ActionState(
                action_id=action.action_id, action_type=action.action_type,
                action_status="RUNNING")
        self._pending_actions = [a.action_id for a in actions]

    def _finish_node_actions(self) -> None:
        for action_id in self._pending_actions:
            state = self.action_states[action_id]
            status = "FAILED" if state.action_type in self.fail_actions else "FINISHED"
            self.action_states[action_id] = state.model_copy(update={"action_status": status})
            self._dirty = True
        self._pending_actions = []

    # ------------------------------------------------------------------ instant actions

    def _instant(self, action_type: str, action_id: str, now_s: float) -> None:
        status = "FINISHED"
        if action_type == "startPause":
            self.paused = True
        elif action_type == "stopPause":
            self.paused = False
        elif action_type == "cancelOrder":
            if not self.held.nodes and not self.held.edges:
                status = "FAILED"
                self._reject("noOrderToCancel", "the vehicle has no order to cancel",
                             [("actionId", action_id)])
            else:
                status = "RUNNING"
                self._cancel = action_id
        elif action_type == "stateRequest":
            self._dirty = True
        elif action_type == "factsheetRequest" and self.version != "2.0.0":
            self._out.append(Publish("factsheet", self.factsheet(now_s)))
        else:
            status = "FAILED"
        self.action_states[action_id] = ActionState(action_id=action_id,
                                                    action_type=action_type,
                                                    action_status=status)  # type: ignore[arg-type]
        self._dirty = True

    def _cancel_done(self) -> None:
        for key, state in self.action_states.items():
            running = state.action_status in ("WAITING", "INITIALIZING", "RUNNING")
            if running and key != self._cancel:
                self.action_states[key] = state.model_copy(update={"action_status": "FAILED"})
        self.held.nodes, self.held.edges = [], []
        assert self._cancel is not None
        cancel = self.action_states[self._cancel]
        self.action_states[self._cancel] = cancel.model_copy(update={"action_status": "FINISHED"})
        self._cancel = None
        self._dirty = True

    # ------------------------------------------------------------------ messages

    def _connection(self, state: ConnectionState, now_s: float) -> Connection:
        return Connection(**self._header("connection", now_s), connection_state=state)

    def _publish_state(self, now_s: float) -> None:
        self._dirty = False
        self._last_state_s = now_s
        x, y = self._xy()
        held = self.held
        msg = State(
            **self._header("state", now_s), order_id=held.order_id,
            order_update_id=held.update_id, last_node_id=self.last_node_id,
            last_node_sequence_id=self.last_node_seq,
            node_states=[NodeState(node_id=n.node_id, sequence_id=n.sequence_id,
                                   released=n.released) for n in held.nodes],
            edge_states=[EdgeState(edge_id=e.edge_id, sequence_id=e.sequence_id,
                                   released=e.released) for e in held.edges],
            driving=self.drive is not None, paused=self.paused,
            action_states=list(self.action_states.values()),
            battery_state=BatteryState(battery_charge=80.0, charging=False),
            operating_mode="AUTOMATIC", errors=list(self.errors),
            safety_state=SafetyState(e_stop="NONE", field_violation=self.field_violation),
            agv_position=AgvPosition(x=x, y=y, theta=self.theta, map_id=self.nodes.map_id,
                                     position_initialized=self.placed))
        self._out.append(Publish("state", msg))

    def _xy(self) -> tuple[float, float]:
        pos = self.nodes.position(self.cell, None)
        return pos.x, pos.y
