"""The master control's side of VDA 5050 for one vehicle, as a sans-I/O state machine (no I/O,
no clock: times are arguments).

The gateway speaks in actions (:class:`protocol.messages.Action`, one per plan step: a move, a
90-degree turn or a wait) and expects started / finished / blocked / unblocked / cancelled /
refused reports back. A vehicle speaks VDA 5050. :class:`VehicleMaster` translates:

* every action is one edge and its end node (a turn's and a wait's edge start and end on the
  same node). The first released actions become an order: its first node is where the vehicle
  stands (the first action's source), the released actions are the base, the planned rest
  (:meth:`VehicleMaster.set_plan`) the horizon. Actions released later extend the base with an
  order update: the same ``orderId``, ``orderUpdateId`` + 1, its first node the decision point
  (the last base node, resent unchanged with the same ``sequenceId``), never a base node before
  it (section 6.6.2). ``sequenceId`` counts 0, 1, 2, ... over nodes and edges of an order;
* ``state`` messages become reports, in the order of the actions and never twice: an action
  whose end node is traversed (``lastNodeSequenceId`` reached its node) is finished (and
  started first if no state showed it started); the next released action is started when the
  vehicle drives (``driving`` and not ``paused``) after traversing its start node. A vehicle
  that does not move on because of an obstacle (a protective field violation, or an error
  that neither rejects an order nor refers to an instant action: a WARNING such as an obstacle,
  or a FATAL one that waits for a human) blocks the action it waits to start; ``unblocked``
  when that clears. States lost on the way (QoS 0) lose no report: the next state carries the
  progress;
* the gateway cancels actions it released but that have not started (a replan): the base
  cannot be taken back, so the master sends ``cancelOrder``; once the vehicle reports it
  finished (or failed: it had no order left) the actions it traversed meanwhile are finished
  and the others cancelled. Released actions the gateway did not cancel go into a new order
  from the vehicle's last node. A new plan's first actions for a vehicle whose order still
  has a horizon cancel that order first too (the vehicle would reject a new order while it
  waits for its horizon, figure 8);
* a vehicle that rejects an order or update (an error referring to its ``orderId``, e.g.
  ``validationError``, ``orderError``, ``orderUpdateError``, ``noRouteError``) refuses its
  first action and, with it, every later released action; the rejection of an update that
  came after a lost one is no refusal (the lost one is resent, then the rest);
* a pick or drop on an action's end node that the vehicle reports FAILED blocks the action
  (:class:`ErrandFailed` asks the gateway); once the gateway gives it up
  (:meth:`VehicleMaster.give_up`) the action is finished;
* instant actions' ids are unique per master instance (``instance``);
* ``pause`` / ``resume`` are the instant actions ``startPause`` / ``stopPause``;
  ``stateRequest`` and ``factsheetRequest`` are sent on request;
* the ``connection`` topic (ONLINE, OFFLINE, the last will CONNECTIONBROKEN) is the link state;
* everything is QoS 0 and may be lost: an order message the vehicle has not acknowledged (its
  state shows an older ``orderUpdateId``) within ``resend_s`` is sent again, with every update
  after the one the vehicle holds, in order (the vehicle ignores a duplicate
  ``orderId``/``orderUpdateId``); so are a pause or resume its ``paused`` does not show and a
  ``cancelOrder`` missing from its ``actionStates`` (:meth:`VehicleMaster.tick`).

The ``orderId`` of an order is ``"<run>.<plan>.<robot>.<first action index>"``: unique for a
run, plan epoch and start, so a master restarted from its journal names it again the same way.
"""

from __future__ import annotations

import re
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from typing import Literal

from protocol.messages import Action, action_run, plan_key
from protocol.vda5050.models import Action as VdaAction
from protocol.vda5050.models import (
    ActionParameter,
    Connection,
    Edge,
    Factsheet,
    Header,
    InstantActions,
    Node,
    Order,
    State,
    VdaError,
    VdaVersion,
)
from protocol.vda5050.nodes import NodeMap
from protocol.vda5050.topics import Headers, TopicName, VehicleTopics

_ORDER_ID = re.compile(r"^((?:[0-9a-z]{1,16}\.)?\d+\.\d+)\.(\d+)(?:r\d+)?$")


def parse_order_id(order_id: str) -> tuple[str, int] | None:
    """``(plan key, first action index)`` of an order id this module gives, else None."""
    m = _ORDER_ID.match(order_id)
    return (m[1], int(m[2])) if m else None


REJECTIONS = frozenset({"validationError", "orderError", "orderUpdateError", "noRouteError"})
"""Error types that mean the vehicle did not take an order over (section 6.6.4)."""

DEPART = "-depart"
"""The suffix of the ``actionId`` of an errand done on the edge that leaves its cell."""


@dataclass(frozen=True, slots=True)
class Errand:
    """A ``kind`` action (``pick`` or ``drop``, blocking HARD) for load ``load_id`` that a
    lifelong shift's errand becomes. Normally on the end node of the action that brings the
    vehicle onto the errand cell (``on_edge`` False), which is finished only once the node
    action is. An errand the vehicle is already on when it is planned (its node was sent
    before) is done on the edge of its next action instead (``on_edge``; HARD: before it
    drives on); its ``action_id`` ends with :data:`DEPART`. ``action_id`` names the errand
    (task and errand index), so a restarted master names it again the same way."""

    kind: Literal["pick", "drop"]
    action_id: str
    load_id: str
    on_edge: bool = False

    def vda_action(self) -> VdaAction:
        """The action as it goes into an order."""
        return VdaAction(action_type=self.kind, action_id=self.action_id, blocking_type="HARD",
                         action_parameters=[
                             ActionParameter(key="stationType", value="floor"),
                             ActionParameter(key="loadType", value="default"),
                             ActionParameter(key="loadId", value=self.load_id)])


def _stops(error: VdaError) -> bool:
    """Whether ``error`` keeps the vehicle from driving on: a WARNING (an obstacle, section
    6.10.5) or a FATAL error (it waits for a human), but not an order's rejection (a refusal)
    nor a complaint about an instant action (``noOrderToCancel`` refers to its actionId; the
    vehicle is not stopped by it)."""
    if error.error_type in REJECTIONS:
        return False
    return not any(r.reference_key == "actionId" for r in error.error_references or ())


def consecutive_ids(key: str, first: int, count: int) -> list[str | None]:
    """The ids of ``count`` actions of plan key ``key`` numbered ``first``, ``first`` + 1, ..."""
    return [f"{key}.{first + k}" for k in range(count)]


ReportKind = Literal["started", "finished", "blocked", "unblocked", "cancelled", "refused"]


@dataclass(frozen=True, slots=True)
class Publish:
    """Send ``message`` on the vehicle's topic ``topic``."""

    topic: TopicName
    message: Header


@dataclass(frozen=True, slots=True)
class Report:
    """What the vehicle did with action ``action_id``, for the executor."""

    kind: ReportKind
    action_id: str
    detail: str = ""


@dataclass(frozen=True, slots=True)
class LinkState:
    """The vehicle's connection changed (``connection`` topic)."""

    online: bool
    state: str


@dataclass(frozen=True, slots=True)
class ErrandFailed:
    """The vehicle reports the pick or drop ``errand`` of action ``action_id`` (on its end
    node, or on its edge) FAILED (section 6.8.2: e.g. the station is unexpectedly empty). The
    action is blocked until the gateway gives the errand up (:meth:`VehicleMaster.give_up`:
    its task no longer needs it), then reported as the vehicle drove it."""

    errand: str
    action_id: str


Effect = Publish | Report | LinkState | ErrandFailed


@dataclass(slots=True)
class _Step:
    """A released action in the current order: its edge's sequence id and its end node."""

    action: Action
    edge_seq: int
    node: Node
    started: bool = False
    finished: bool = False
    blocked: bool = False
    errand: str | None = None
    """The ``actionId`` of the pick/drop on its end node, if it has one."""
    depart: str | None = None
    """The ``actionId`` of the pick/drop on its edge (done before the vehicle drives it)."""

    @property
    def node_seq(self) -> int:
        return self.edge_seq + 1


@dataclass(slots=True)
class _Sent:
    """An order message and when it was last sent."""

    order: Order
    sent_s: float
    first_step: int


@dataclass(slots=True)
class _Order:
    """The order the vehicle holds or is being sent."""

    order_id: str
    start: Node
    steps: list[_Step] = field(default_factory=list)
    sent: list[_Sent] = field(default_factory=list)
    cancel_id: str | None = None
    dead: bool = False
    base_update: int = 0
    """The ``orderUpdateId`` of ``sent[0]`` (more than 0 for an order taken over)."""
    horizon: bool = False
    """The vehicle holds unreleased nodes of this order."""
    adopting: dict[str, int] = field(default_factory=dict)
    """Taken over from the vehicle: action id -> edge sequence id, until the gateway resends
    the action."""

    def decision_point(self) -> Node:
        """The last base node, as it was first sent."""
        return self.steps[-1].node if self.steps else self.start


class VehicleMaster:
    """Drives one vehicle (see the module docstring). Feed it the gateway's releases, cancels
    and pauses and the vehicle's messages; take what :meth:`drain` returns, in order.

    ``continuous`` (a lifelong shift, where the actions of a robot are numbered over the whole
    run and each planning call's segment has its own plan key): actions that continue the
    robot's last released one extend the current order whatever their plan key; a new order
    starts only once the vehicle finished the current one. ``errand(action)``: the picks and
    drops (:class:`Errand`) of an action being released. ``ids(key, first, count)``: the ids
    of ``count`` consecutive actions of an order named after action ``first`` of plan key
    ``key`` (to take an order over after a restart; by default their indices count up by
    one; None for an action the gateway has forgotten, one it finished long ago)."""

    def __init__(self, topics: VehicleTopics, version: VdaVersion, nodes: NodeMap, *,
                 resend_s: float = 1.0, continuous: bool = False,
                 errand: Callable[[Action], Sequence[Errand]] | None = None,
                 ids: Callable[[str, int, int], list[str | None]] = consecutive_ids,
                 instance: str = "", max_steps: int = 64) -> None:
        self.topics = topics
        self.max_steps = max_steps
        """``continuous``: an order grows to at most this many actions; later ones wait for a
        new order once the vehicle has done it. A vehicle keeps the state of every action of
        its order until a new one comes (section 6.10.6, ``actionStates``), so one order
        for a whole shift would make every state message longer as the shift goes on."""
        self.instance = instance
        """Part of every instant action's ``actionId``: one per master instance (the gateway
        gives a fresh one each start), so that a restarted master never reuses an id the
        vehicle still lists (``actionId`` is unique, section 6.8; a reused ``cancelOrder-1``
        would look FINISHED at once)."""
        self.version = version
        self.nodes = nodes
        self.resend_s = resend_s
        self.continuous = continuous
        self.errand = errand
        self.ids = ids
        self.online = False
        self.state: State | None = None
        self.factsheet: Factsheet | None = None
        """The vehicle's factsheet, once it sent one (retained, or asked for)."""
        self._order: _Order | None = None
        self._plan: list[Action] = []
        self._carry: list[Action] = []
        self._cancelled: set[str] = set()
        self._given_up: set[str] = set()
        self._header = Headers(version, topics)
        self._instant = 0
        self._want_paused: bool | None = None
        self._pause_sent_s = 0.0
        self._cancel_sent_s = 0.0
        self._effects: list[Effect] = []

    # ------------------------------------------------------------------ gateway -> vehicle

    def set_plan(self, actions: Sequence[Action]) -> None:
        """The robot's planned actions of the current plan (the horizon is the part after the
        last released one); an empty sequence sends no horizon."""
        self._plan = list(actions)

    def release(self, actions: Sequence[Action], now_s: float) -> None:
        """The gateway released ``actions`` (in index order, after those released before):
        extend the base with an order update, or start a new order."""
        if not actions:
            return
        order = self._order
        live = order is not None and not order.dead
        other_plan = order is None or not (
            self._continues(order, actions[0]) if self.continuous
            else order.order_id.startswith(plan_key(actions[0].action_id) + "."))
        if live and order is not None and order.cancel_id is not None:
            self._carry.extend(actions)  # a new order once the cancelOrder completes
        elif self.continuous and live and order is not None and (
                self._carry or (not other_plan and len(order.steps) >= self.max_steps)):
            self._carry.extend(actions)  # a new order once the vehicle has done this one
        elif live and order is not None and other_plan and order.horizon:
            # the vehicle waits for its old order's horizon: it would reject a new order
            # (figure 8), so that order is cancelled first
            self._carry.extend(actions)
            order.cancel_id = self._instant_action("cancelOrder", now_s)
            self._cancel_sent_s = now_s
        elif not live or other_plan:
            self._new_order(list(actions), now_s)
        else:
            assert order is not None
            self._update(order, list(actions), now_s)

    @staticmethod
    def _continues(order: _Order, action: Action) -> bool:
        """Whether ``action`` follows the order's last step while the vehicle still drives it
        (in a lifelong shift; once it is done a new order starts)."""
        if not order.steps or order.steps[-1].finished:
            return False
        last = order.steps[-1].action
        return (action.sequence == last.sequence + 1
                and action_run(action.action_id) == action_run(last.action_id)
                and tuple(action.src.cell) == tuple(last.dst.cell))

    def cancel(self, action_ids: Iterable[str], now_s: float) -> None:
        """The gateway cancels these released, unstarted actions (a replan)."""
        order = self._order
        ids = set(action_ids)
        carried = [a for a in self._carry if a.action_id in ids]
        for action in carried:
            self._carry.remove(action)
            self._emit(Report("cancelled", action.action_id))
        ids -= {a.action_id for a in carried}
        if order is None or not ids:
            return
        live = {s.action.action_id for s in order.steps if not s.finished}
        self._cancelled |= ids & live
        if not (ids & live) or order.cancel_id is not None or order.dead:
            return
        order.cancel_id = self._instant_action("cancelOrder", now_s)
        self._cancel_sent_s = now_s

    def pause(self, now_s: float) -> None:
        """Stop driving (``startPause``); the order is kept."""
        self._want_paused = True
        self._pause_sent_s = now_s
        self._instant_action("startPause", now_s)

    def resume(self, now_s: float) -> None:
        """Drive on (``stopPause``)."""
        self._want_paused = False
        self._pause_sent_s = now_s
        self._instant_action("stopPause", now_s)

    def request_state(self, now_s: float) -> None:
        """Ask for a ``state`` message now (``stateRequest``)."""
        self._instant_action("stateRequest", now_s)

    def request_factsheet(self, now_s: float) -> None:
        """Ask for the ``factsheet`` (``factsheetRequest``)."""
        self._instant_action("factsheetRequest", now_s)

    def give_up(self, errand: str, now_s: float) -> None:
        """The gateway gives up the FAILED pick or drop ``errand`` (:class:`ErrandFailed`):
        the action it waited on is finished (reports follow from the last state)."""
        self._given_up.add(errand)
        order, state = self._order, self.state
        if order is not None and not order.dead and state is not None \
                and state.order_id == order.order_id:
            self._progress(order, state)
            self._follow_on(order, now_s)

    def _follow_on(self, order: _Order, now_s: float) -> None:
        """Actions held back from a full order (``max_steps``) go out as a new order once
        the vehicle has done the current one."""
        if (self._carry and order.cancel_id is None and not order.dead
                and all(step.finished for step in order.steps)):
            carry, self._carry = self._carry, []
            self._new_order(carry, now_s)

    def adopt(self, state: State) -> tuple[list[str], list[str]]:
        """After a restart: take over the order ``state`` shows, if this master (or its
        predecessor) named it (``<plan key>.<first action>``). Returns the ids of the actions
        the vehicle finished in it and of those still in its base; :meth:`adopt_actions`
        then takes the base's actions as the gateway resends them. An action whose end node
        the vehicle reached while its pick or drop there has not finished is in the base (it
        finishes with that node action, which is not sent again)."""
        self.state = state
        parsed = parse_order_id(state.order_id)
        if parsed is None or self._order is not None:
            return [], []
        key, first = parsed
        done = state.last_node_sequence_id // 2
        base = sorted(e.sequence_id for e in state.edge_states if e.released)
        ids = self.ids(key, first, done + len(base))
        if len(ids) < done + len(base):
            return [], []  # not an order of the gateway's current plan
        if done and not state.driving and any(
                a.action_type in ("pick", "drop") and not a.action_id.endswith(DEPART)
                and a.action_status not in ("WAITING", "FINISHED") for a in state.action_states):
            done -= 1  # its pick or drop on the last node it reached has not finished
            base.insert(0, 2 * done + 1)
        position = state.agv_position
        cell = (self.nodes.cell_of(position.x, position.y) if position is not None
                else (0, 0))
        start = Node(node_id=state.last_node_id, sequence_id=state.last_node_sequence_id,
                     released=True, node_position=self.nodes.position(cell, None))
        self._order = _Order(order_id=state.order_id, start=start,
                             base_update=state.order_update_id + 1,
                             horizon=any(not n.released for n in state.node_states),
                             adopting={aid: seq for seq in base
                                       if (aid := ids[(seq - 1) // 2]) is not None})
        return ([aid for aid in ids[:done] if aid is not None],
                [aid for seq in base if (aid := ids[(seq - 1) // 2]) is not None])

    def adopt_actions(self, actions: Sequence[Action]) -> list[Action]:
        """Of ``actions`` (resent by the gateway, in index order), take those in the base of
        an order taken over as its steps; returns the others (to release)."""
        order = self._order
        rest: list[Action] = []
        for action in actions:
            seq = None if order is None else order.adopting.pop(action.action_id, None)
            if order is None or seq is None:
                rest.append(action)
                continue
            order.steps.append(self._step(action, seq)[0])
        return rest

    def tick(self, now_s: float) -> None:
        """Send again what the vehicle has not acted on for ``resend_s``: order messages it
        does not hold, a pause or resume its ``paused`` does not show, a cancelOrder it does
        not list."""
        order, state = self._order, self.state
        due = now_s - self.resend_s
        if (state is not None and state.paused is not None and self._want_paused is not None
                and state.paused != self._want_paused and self._pause_sent_s <= due):
            (self.pause if self._want_paused else self.resume)(now_s)
        if (order is not None and order.cancel_id is not None and not order.dead
                and state is not None and self._cancel_sent_s <= due
                and all(a.action_id != order.cancel_id for a in state.action_states)):
            self._cancel_sent_s = now_s
            self._emit(Publish("instantActions", self._instant_message(
                "cancelOrder", order.cancel_id, now_s)))
        if order is None or order.dead or not order.sent:
            return
        if all(step.finished for step in order.steps):
            return  # done: a vehicle showing another order must not get this one again
        held = state.order_update_id if state and state.order_id == order.order_id else -1
        pending = order.sent[max(0, held + 1 - order.base_update):]
        if pending and now_s - pending[0].sent_s >= self.resend_s:
            for sent in pending:  # the same order message under a new header: headerId
                sent.sent_s = now_s  # counts every message sent (section 6.4)
                self._emit(Publish("order", sent.order.model_copy(
                    update=self._header("order", now_s))))

    # ------------------------------------------------------------------ vehicle -> gateway

    def receive_connection(self, msg: Connection) -> None:
        """The vehicle's ``connection`` message (or its last will)."""
        online = msg.connection_state == "ONLINE"
        if online != self.online:
            self.online = online
            self._emit(LinkState(online, msg.connection_state))

    def receive_factsheet(self, msg: Factsheet) -> None:
        """The vehicle's ``factsheet`` (section 6.15)."""
        self.factsheet = msg

    def receive_state(self, msg: State, now_s: float) -> None:
        """A ``state`` message: reports for the executor."""
        self.state = msg
        order = self._order
        if order is None or order.dead:
            return
        if self._rejected(order, msg):
            return
        if msg.order_id != order.order_id:
            return  # the vehicle does not hold this order yet (tick() resends it)
        self._progress(order, msg)
        if order.cancel_id is not None:
            status = next((a.action_status for a in msg.action_states
                           if a.action_id == order.cancel_id), None)
            if status in ("FINISHED", "FAILED"):
                self._cancel_done(order, now_s)
        else:
            self._follow_on(order, now_s)

    def drain(self) -> list[Effect]:
        """What to send and report, in order (then cleared)."""
        effects, self._effects = self._effects, []
        return effects

    # ------------------------------------------------------------------ internals

    def _emit(self, effect: Effect) -> None:
        self._effects.append(effect)

    def _instant_action(self, action_type: str, now_s: float) -> str:
        self._instant += 1
        action_id = f"{action_type}-{self.instance}{self._instant}"
        self._emit(Publish("instantActions",
                           self._instant_message(action_type, action_id, now_s)))
        return action_id

    def _instant_message(self, action_type: str, action_id: str,
                         now_s: float) -> InstantActions:
        return InstantActions(**self._header("instantActions", now_s),
                              actions=[VdaAction(action_type=action_type, action_id=action_id,
                                                 blocking_type="HARD")])

    def _node(self, action: Action, seq: int, released: bool,
              errands: Sequence[Errand] = ()) -> Node:
        dst = action.dst
        return Node(node_id=self.nodes.node_id(dst.cell), sequence_id=seq, released=released,
                    node_position=self.nodes.position(dst.cell, dst.heading),
                    actions=[e.vda_action() for e in errands if not e.on_edge])

    def _edge(self, action: Action, seq: int, released: bool,
              errands: Sequence[Errand] = ()) -> Edge:
        src, dst = self.nodes.node_id(action.src.cell), self.nodes.node_id(action.dst.cell)
        return Edge(edge_id=self.nodes.edge_id(action.src.cell, action.dst.cell),
                    sequence_id=seq, released=released, start_node_id=src, end_node_id=dst,
                    actions=[e.vda_action() for e in errands if e.on_edge])

    def _step(self, action: Action, edge_seq: int) -> tuple[_Step, Edge]:
        """A released action as a step of the order (its node as first sent: its errand
        included) and its edge (an errand on it only if the vehicle does not hold it yet)."""
        errands = list(self.errand(action)) if self.errand is not None else []
        held = {a.action_id for a in self.state.action_states} if self.state else set()
        errands = [e for e in errands if not (e.on_edge and e.action_id in held)]
        node = self._node(action, edge_seq + 1, True, errands)
        step = _Step(action, edge_seq, node, errand=next(
            (e.action_id for e in errands if not e.on_edge), None), depart=next(
            (e.action_id for e in errands if e.on_edge), None))
        return step, self._edge(action, edge_seq, True, errands)

    def _horizon(self, last: Action, seq: int) -> tuple[list[Node], list[Edge]]:
        """Nodes and edges of the planned actions after ``last``, from sequence id ``seq``."""
        after = [a for a in self._plan if plan_key(a.action_id) == plan_key(last.action_id)
                 and a.sequence > last.sequence]
        nodes: list[Node] = []
        edges: list[Edge] = []
        for action in after:
            edges.append(self._edge(action, seq, False))
            nodes.append(self._node(action, seq + 1, False))
            seq += 2
        return nodes, edges

    def _send(self, order: _Order, nodes: list[Node], edges: list[Edge], first_step: int,
              now_s: float) -> None:
        last = order.steps[-1].action if order.steps else None
        h_nodes, h_edges = self._horizon(last, len(nodes) + len(edges) + nodes[0].sequence_id) \
            if last else ([], [])
        msg = Order(**self._header("order", now_s),
                    order_id=order.order_id, order_update_id=order.base_update + len(order.sent),
                    nodes=nodes + h_nodes, edges=edges + h_edges)
        order.horizon = bool(h_nodes)
        order.sent.append(_Sent(msg, now_s, first_step))
        self._emit(Publish("order", msg))

    def _new_order(self, actions: list[Action], now_s: float) -> None:
        first = actions[0]
        start = Node(node_id=self.nodes.node_id(first.src.cell), sequence_id=0, released=True,
                     node_position=self.nodes.position(first.src.cell, first.src.heading))
        order_id = f"{plan_key(first.action_id)}.{first.sequence}"
        if self.state is not None and self.state.order_id.startswith(order_id):
            order_id += f"r{self.state.order_update_id + 1}"  # never reuse the vehicle's id
        order = _Order(order_id=order_id, start=start)
        self._order = order
        self._append(order, [start], actions, now_s)

    def _update(self, order: _Order, actions: list[Action], now_s: float) -> None:
        self._append(order, [order.decision_point()], actions, now_s)

    def _append(self, order: _Order, nodes: list[Node], actions: list[Action],
                now_s: float) -> None:
        first_step = len(order.steps)
        edges: list[Edge] = []
        seq = nodes[0].sequence_id + 1
        for action in actions:
            step, edge = self._step(action, seq)
            order.steps.append(step)
            edges.append(edge)
            nodes.append(step.node)
            seq += 2
        self._send(order, nodes, edges, first_step, now_s)

    def _rejected(self, order: _Order, msg: State) -> bool:
        """Refuse the actions of an order message the vehicle rejected; True if it did."""
        for error in msg.errors:
            refs = {r.reference_key: r.reference_value for r in error.error_references or ()}
            if error.error_type not in REJECTIONS or refs.get("orderId") != order.order_id:
                continue
            update = refs.get("orderUpdateId")
            held = msg.order_update_id if msg.order_id == order.order_id else -1
            index = int(update) if update and update.isdigit() else held + 1
            i = index - order.base_update
            if index != held + 1 or not 0 <= i < len(order.sent):
                continue  # stale, or an update after a lost one: tick() resends the gap
            first = order.sent[i].first_step
            for step in order.steps[first:]:
                if not step.finished:
                    self._emit(Report("refused", step.action.action_id,
                                      f"{error.error_type}: {error.error_description or ''}"))
            del order.steps[first:]
            del order.sent[i:]
            if not order.steps:
                order.dead = True
            return True
        return False

    def _progress(self, order: _Order, msg: State) -> None:
        reached = msg.last_node_sequence_id
        obstacle = msg.safety_state.field_violation or any(map(_stops, msg.errors))
        moving = msg.driving and not msg.paused
        status: dict[str, str] | None = None
        for i, step in enumerate(order.steps):
            if step.finished:
                continue
            aid = step.action.action_id
            if step.depart is not None and not step.started:
                if status is None:
                    status = {a.action_id: a.action_status for a in msg.action_states}
                if status.get(step.depart) == "FAILED" and step.depart not in self._given_up:
                    if not step.blocked:  # the pick or drop before it drives off failed
                        step.blocked = True
                        self._emit(Report("blocked", aid))
                        self._emit(ErrandFailed(step.depart, aid))
                    break
            if step.node_seq <= reached:
                if not step.started:
                    self._started(step)
                if step.errand is not None:
                    if status is None:
                        status = {a.action_id: a.action_status for a in msg.action_states}
                    errand = status.get(step.errand)
                    done = errand == "FINISHED" or (
                        errand == "FAILED" and step.errand in self._given_up)
                    if not done:  # the pick or drop there runs (or failed)
                        if (errand == "FAILED") != step.blocked:
                            step.blocked = errand == "FAILED"
                            self._emit(Report("blocked" if step.blocked else "unblocked", aid))
                            if step.blocked:
                                self._emit(ErrandFailed(step.errand, aid))
                        break
                    self._given_up.discard(step.errand)
                    if step.blocked:
                        step.blocked = False
                        self._emit(Report("unblocked", aid))
                step.finished = True
                self._emit(Report("finished", aid))
                continue
            first_open = i == 0 or order.steps[i - 1].finished
            if not first_open or step.started:
                break
            if step.edge_seq - 1 <= reached and moving and aid not in self._cancelled:
                self._started(step)
            elif obstacle and not step.blocked:
                step.blocked = True
                self._emit(Report("blocked", aid))
            elif not obstacle and step.blocked and aid not in self._cancelled:
                step.blocked = False
                self._emit(Report("unblocked", aid))
            break

    def _started(self, step: _Step) -> None:
        if step.blocked:
            step.blocked = False
            self._emit(Report("unblocked", step.action.action_id))
        step.started = True
        self._emit(Report("started", step.action.action_id))

    def _cancel_done(self, order: _Order, now_s: float) -> None:
        """The vehicle stands still without its order: cancelled or re-sent actions."""
        order.dead = True
        rest = [s for s in order.steps if not s.finished]
        carry: list[Action] = []
        for step in rest:
            aid = step.action.action_id
            if aid in self._cancelled:
                self._emit(Report("cancelled", aid))
            else:
                carry.append(step.action)
        self._cancelled.clear()
        carry.extend(self._carry)
        self._carry = []
        if carry:
            self._new_order(carry, now_s)
