"""The message models of protocol v3, which also serves v1 and v2 peers
(:data:`PROTOCOL_VERSION`; see :mod:`protocol` for the message flow).

Every message carries ``type`` (the discriminator), ``v`` (protocol version), ``msg_id`` (unique
per sender) and ``seq`` (per-sender counter, +1 per message on a connection). Unknown fields are
rejected (``extra="forbid"``). Cells are ``[x, y]`` (x the column, y the row), times are
milliseconds.
"""

from __future__ import annotations

import functools
import re
from enum import IntEnum, StrEnum
from typing import Annotated, Any, Literal

from pydantic import BaseModel, ConfigDict, Field, field_validator, model_validator

PROTOCOL_VERSION: Literal[3] = 3
"""The version this module speaks (the default ``v`` of every message).

Version 2 adds the ``turning`` motion model: an action's ``src`` and ``dst`` poses carry
headings, a turn is an action whose cell stays (only the heading changes by 90 degrees) and a
move keeps its heading and goes one cell forward; and a ``blocked`` after ``started`` reports a
move stopped on the way (a bumper contact), which a ``cancel`` may then void (the robot goes
back to the move's source cell and answers ``cancelled``); a robot may refuse an action
(``refused``, e.g. its start pose or heading is not the robot's).

Version 3 sends one message less per action: a robot sends no ``ack``. Its first answer about
an action acknowledges it (``started`` or ``blocked`` when it takes it up, ``refused``,
``cancelled``); an action it holds is listed in ``hello.acked`` as before, so the resends
are unchanged. A robot that refuses an action answers every action it drops with it, queued
ones included, with ``refused`` (``queued_behind``), so the gateway knows which refusals are
still to come without an ``ack``. A robot's ``hello`` fixes the version of its connection: the
gateway answers in it, and serves version 1 robots (no headings: ``omni`` plans only) and
version 2 robots (with ``ack``) beside version 3 ones."""

SUPPORTED_VERSIONS: tuple[int, ...] = (1, 2, 3)
"""The versions a peer may speak."""

ProtocolVersion = Literal[1, 2, 3]

FOLDED_ACK = 3
"""The first version whose robots send no ``ack`` (see :data:`PROTOCOL_VERSION`)."""

MAX_MESSAGE_BYTES = 64 * 1024
"""Largest message (encoded JSON) a peer must accept; larger ones are refused."""

Cell = tuple[Annotated[int, Field(ge=0)], Annotated[int, Field(ge=0)]]
"""A grid cell ``[x, y]``."""

Heading = Literal["E", "N", "W", "S"]
"""Compass heading of a robot (only meaningful for the ``turning`` motion model)."""

HEADINGS: tuple[Heading, ...] = ("E", "S", "W", "N")
"""The compass heading of a plan's heading number (0 east (+x), 1 south (+y), 2 west, 3 north:
DESIGN's ``turning`` motion model), e.g. ``HEADINGS[1] == "S"``."""

PlanHeading = Annotated[int, Field(ge=0, le=3)]
"""A plan's heading number (see :data:`HEADINGS`)."""

RobotId = Annotated[int, Field(ge=0)]
"""A robot is the agent with this index in the instance."""

MsgId = Annotated[str, Field(min_length=1, max_length=64)]

_ACTION_ID = re.compile(r"^(?:([0-9a-z]{1,16})\.)?(\d+)\.(\d+)\.(\d+)$")
ActionId = Annotated[str, Field(pattern=_ACTION_ID.pattern, max_length=48)]
"""``"<run>.<plan>.<robot>.<index>"``: action ``index`` (a_index^robot) of plan epoch ``plan``
of run ``run`` (1-16 lower-case letters and digits). A gateway with a journal gives every run an
id that never repeats across runs or restarts; without a journal the first run of the process
has the empty id and its actions are ``"<plan>.<robot>.<index>"``."""


def action_id(plan: int, robot: int, index: int, run: str = "") -> str:
    """The action id of action ``index`` of ``robot`` in plan epoch ``plan`` of run ``run``."""
    return f"{run}.{plan}.{robot}.{index}" if run else f"{plan}.{robot}.{index}"


@functools.lru_cache(maxsize=1 << 16)
def _split_action_id(value: str) -> tuple[str, int, int, int] | None:
    """``(run, plan, robot, index)``, or None. Cached: the gateway reads one action's id about
    five times (its own ``action``, the robot's ``ack``, ``started`` and ``finished``, the
    executor's report), and a recent id costs one dictionary lookup instead of a regex match
    and three ``int()`` calls."""
    m = _ACTION_ID.match(value)
    return None if m is None else (m[1] or "", int(m[2]), int(m[3]), int(m[4]))


def parse_action_id(value: str) -> tuple[int, int, int]:
    """``(plan, robot, index)`` of an action id; ValueError if it is not one."""
    parts = _split_action_id(value)
    if parts is None:
        raise ValueError("not an action id (expected '<run>.<plan>.<robot>.<index>' or "
                         f"'<plan>.<robot>.<index>'): {value!r}")
    return parts[1:]


def action_run(value: str) -> str:
    """The run id of an action id (empty if it has none); ValueError if it is not one."""
    parts = _split_action_id(value)
    if parts is None:
        raise ValueError(f"not an action id: {value!r}")
    return parts[0]


def plan_key(action_id: str) -> str:
    """The part of an action id that names its run, plan and robot (all but the index): the
    actions of one plan of one robot share it."""
    return action_id.rsplit(".", 1)[0]


class _Model(BaseModel):
    """Strict base of every nested structure."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)


def _require_version(schema: dict[str, Any]) -> None:
    """On the wire ``v`` and ``type`` are mandatory even though the models fill them in."""
    required = schema.setdefault("required", [])
    if isinstance(required, list):
        required[:0] = [k for k in ("v", "type") if k not in required]


class Envelope(_Model):
    """Fields common to every message; ``v`` and ``type`` must be present on the wire."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False,
                              json_schema_extra=_require_version)

    v: ProtocolVersion = PROTOCOL_VERSION
    msg_id: MsgId
    seq: Annotated[int, Field(ge=0)]

    @field_validator("v", mode="before")
    @classmethod
    def _version_is_an_integer(cls, value: Any) -> Any:
        """``true`` and ``1.0`` equal 1 in Python but are not a version number."""
        if type(value) is not int:
            raise ValueError("v must be an integer (a protocol version)")
        return value


class Pose(_Model):
    """Where a robot is: its cell, and its heading if the motion model has one."""

    cell: Cell
    heading: Heading | None = None


RobotActivity = Literal["idle", "received", "running", "blocked", "paused", "disconnected"]
"""What a robot is doing: ``received`` = holds an action it has not started yet."""


class Activity(_Model):
    """The action a robot currently holds and what it does with it."""

    action_id: ActionId
    state: Literal["received", "running", "blocked"]


# --------------------------------------------------------------------------------------------
# robot -> gateway


class Hello(Envelope):
    """First message of a robot connection: who it is and a snapshot of what it is doing.

    ``acked`` are ids of actions it holds (received, not finished); ``finished`` ids of actions
    it finished (at least those whose ``finished`` report may have been lost). The gateway
    applies missing finishes and answers with ``welcome``, resending only what it does not hold.
    """

    type: Literal["hello"] = "hello"
    robot_id: RobotId
    pose: Pose | None = None
    acked: list[ActionId] = Field(default_factory=list, max_length=256)
    finished: list[ActionId] = Field(default_factory=list, max_length=256)
    current: Activity | None = None


class Ack(Envelope):
    """The robot received action ``action_id`` (and will drop any duplicate of it). Protocol
    v1 and v2 only: a v3 robot's first report about an action acknowledges it."""

    type: Literal["ack"] = "ack"
    action_id: ActionId


class _ActionReport(Envelope):
    """A report about one of the sender's own actions, with its pose at that moment."""

    action_id: ActionId
    pose: Pose | None = None


class Started(_ActionReport):
    """The robot began to move (its target cell was free)."""

    type: Literal["started"] = "started"


class Finished(_ActionReport):
    """The robot arrived at the action's target."""

    type: Literal["finished"] = "finished"


class Blocked(_ActionReport):
    """The action's target cell is taken; the robot waits and re-checks."""

    type: Literal["blocked"] = "blocked"


class Unblocked(_ActionReport):
    """The target cell became free again (a ``started`` follows)."""

    type: Literal["unblocked"] = "unblocked"


class Cancelled(_ActionReport):
    """The robot confirms a ``cancel``: it dropped the action and stays where it is."""

    type: Literal["cancelled"] = "cancelled"


RefuseCode = Literal["pose_mismatch", "cannot_execute", "queued_behind"]
"""Why a robot refuses an action: its ``src`` pose is not where the robot stands when the
action is due (``pose_mismatch``), its body cannot execute it (``cannot_execute``), or it
comes after an action of the same plan the robot refused (``queued_behind``)."""


class ActionRefused(_ActionReport):
    """Protocol v2: the robot will not execute ``action_id`` (instead of ``ack``, or of
    ``started`` if it finds out when the action is due) and drops every action of the same
    plan after it; ``code`` says why, ``detail`` in words, ``pose`` is where the robot is. The
    gateway takes the action, and those it dispatched to the robot after it, as not executed."""

    type: Literal["refused"] = "refused"
    code: RefuseCode
    detail: Annotated[str, Field(max_length=500)] = ""


class State(Envelope):
    """Periodic snapshot of the robot (every few seconds, VDA 5050 style)."""

    type: Literal["state"] = "state"
    robot_id: RobotId
    pose: Pose | None = None
    activity: RobotActivity = "idle"
    current: Activity | None = None
    battery: Annotated[float, Field(ge=0, le=1)] | None = None


# --------------------------------------------------------------------------------------------
# gateway -> robot


class Action(Envelope):
    """Execute this action now: all its ADG dependencies are done (VDA 5050 "released").

    ``sequence`` is the action's index i in the robot's plan; it matches ``action_id``.
    """

    type: Literal["action"] = "action"
    action_id: ActionId
    sequence: Annotated[int, Field(ge=0)]
    src: Pose
    dst: Pose
    duration_ms: Annotated[float, Field(gt=0)]

    @model_validator(mode="after")
    def _sequence_matches_id(self) -> Action:
        if parse_action_id(self.action_id)[2] != self.sequence:
            raise ValueError(f"sequence {self.sequence} does not match {self.action_id}")
        return self


class Welcome(Envelope):
    """Answer to ``hello``: the robot's assigned start and the actions it must (re)execute.

    ``resend`` holds, in order, every dispatched action the gateway has no ``finished`` for and
    that the ``hello`` did not report held (``acked``, ``current``), each with ``msg_id``
    ``"resend-<action_id>"`` and ``seq`` 0; a robot drops any it holds already. ``drop`` lists
    the actions the robot said it holds that the gateway does not stand behind (of another run
    or plan): the robot MUST NOT start them (it drops them before it starts anything, as for a
    ``cancel``). Cancels still owed follow as ``cancel`` messages.
    """

    type: Literal["welcome"] = "welcome"
    robot_id: RobotId
    start: Pose | None = None
    plan: Annotated[int, Field(ge=0)] | None = None
    resend: list[Action] = Field(default_factory=list)
    drop: list[ActionId] = Field(default_factory=list, max_length=257)
    """At most what a ``hello`` can list as held (``acked`` and ``current``)."""
    state_period_ms: Annotated[float, Field(gt=0)] = 5000.0
    paused: bool = False


class CancelAction(Envelope):
    """Drop this action if it has not started to move; answer ``cancelled`` (or, if already
    moving, finish it and answer ``finished``)."""

    type: Literal["cancel"] = "cancel"
    action_id: ActionId


class Pause(Envelope):
    """Start no new move until ``resume`` (a running move completes).

    Sent by an operator it pauses the whole fleet: the gateway stops dispatching and sends
    ``pause`` to every robot.
    """

    type: Literal["pause"] = "pause"
    reason: str = ""


class Resume(Envelope):
    """Continue after ``pause`` (from an operator: resume the fleet and dispatching)."""

    type: Literal["resume"] = "resume"


class ErrorCode(StrEnum):
    """Why the gateway refused a message (VDA 5050 style explicit rejection)."""

    MALFORMED = "malformed"  # not JSON, or not a JSON object
    TOO_LARGE = "too_large"  # over MAX_MESSAGE_BYTES
    UNSUPPORTED_VERSION = "unsupported_version"
    UNKNOWN_TYPE = "unknown_type"
    INVALID = "invalid"  # a known type whose fields do not validate
    FORBIDDEN = "forbidden"  # this role may not send this type
    NOT_YOURSELF = "not_yourself"  # a robot reporting about another robot
    UNKNOWN_ACTION = "unknown_action"  # never dispatched to this robot
    DUPLICATE = "duplicate"  # already applied (e.g. a second finish); ignored
    REJECTED = "rejected"  # the executor refused the event (out of order, ...)
    BAD_STATE = "bad_state"  # command not possible now (e.g. start with nothing loaded)
    BAD_REQUEST = "bad_request"  # command arguments wrong (unknown map, ...)
    RATE_LIMITED = "rate_limited"
    INTERNAL = "internal"


class CloseCode(IntEnum):
    """Why the gateway closed a websocket (RFC 6455 codes, 4000-4999 fleetgate's own).

    A bad frame gets an ``error`` reply (:class:`ErrorCode`); the connection is closed only for
    the reasons below.
    """

    NORMAL = 1000  # the peer or the gateway ended the session
    GOING_AWAY = 1001  # the gateway is shutting down
    INVALID_UTF8 = 1007  # a text frame that is not UTF-8 (closed by the websocket layer)
    POLICY = 1008  # too many protocol errors in a short time (the error budget is spent)
    TOO_BIG = 1009  # a frame over the hard limit (4 x MAX_MESSAGE_BYTES)
    INTERNAL = 1011  # the gateway failed while handling this connection (logged)
    TRY_AGAIN = 1013  # the peer read too slowly: its send queue was full
    REPLACED = 4000  # the same robot connected again; this older connection is dropped
    HELLO_TIMEOUT = 4001  # a robot did not say hello within hello_timeout_s
    IDLE_TIMEOUT = 4002  # a robot sent nothing for idle_timeout_s


class Error(Envelope):
    """A message was refused; ``ref`` is its ``msg_id`` when it could be read."""

    type: Literal["error"] = "error"
    code: ErrorCode
    ref: str | None = None
    detail: str = ""


class Ok(Envelope):
    """An operator command ``ref`` was accepted."""

    type: Literal["ok"] = "ok"
    ref: str
    detail: str = ""


# --------------------------------------------------------------------------------------------
# operator -> gateway (commands)


class GenerateParams(_Model):
    """Ask the gateway to generate a scenario on the map instead of naming one."""

    seed: int = 0
    kind: Literal["random"] = "random"


class LoadInstance(Envelope):
    """Load map + scenario (or generate starts/goals) with the first ``agents`` agents, plan."""

    type: Literal["load_instance"] = "load_instance"
    map: Annotated[str, Field(min_length=1, max_length=200)]
    scen: Annotated[str, Field(min_length=1, max_length=200)] | None = None
    generate: GenerateParams | None = None
    agents: Annotated[int, Field(ge=1, le=10000)]


class LoadPlan(Envelope):
    """Execute these paths (one per robot, ``path[t]`` its cell at step t) on map ``map``;
    with ``headings`` (one per cell of each path) a plan of the ``turning`` motion model."""

    type: Literal["load_plan"] = "load_plan"
    map: Annotated[str, Field(min_length=1, max_length=200)]
    paths: list[list[Cell]] = Field(min_length=1)
    headings: list[list[PlanHeading]] | None = None


class Start(Envelope):
    """Start executing the loaded plan."""

    type: Literal["start"] = "start"


class ReplanNow(Envelope):
    """Trigger a replan immediately (policy "operator")."""

    type: Literal["replan_now"] = "replan_now"


class StopShift(Envelope):
    """End the running lifelong shift: nothing new is dispatched or planned, robots finish
    what they were dispatched, then the shift is done."""

    type: Literal["stop_shift"] = "stop_shift"


PolicyName = Literal["none", "random", "slack", "operator", "informed", "shadow", "reschedule",
                     "reschedule+slack"]


class SetPolicy(Envelope):
    """Choose the replanning policy (``seed`` for "random")."""

    type: Literal["set_policy"] = "set_policy"
    policy: PolicyName
    seed: int = 0


class SetThreshold(Envelope):
    """Set Δ̄T, the fleet-slack threshold of the "slack" policy."""

    type: Literal["set_threshold"] = "set_threshold"
    threshold_ms: Annotated[float, Field(ge=0)]


class SetSpeed(Envelope):
    """Demo aid: the simulated world runs ``speed`` times faster than plan time."""

    type: Literal["set_speed"] = "set_speed"
    speed: Annotated[float, Field(gt=0, le=100)]


class PlaceIntruder(Envelope):
    """Demo aid: the world connection puts an intruder on ``cell`` for ``duration_ms``.

    The gateway forwards it to "world" connections; the executor never sees it.
    """

    type: Literal["place_intruder"] = "place_intruder"
    cell: Cell
    duration_ms: Annotated[float, Field(gt=0)]


class GetSnapshot(Envelope):
    """Ask for a fresh ``snapshot``."""

    type: Literal["get_snapshot"] = "get_snapshot"


# --------------------------------------------------------------------------------------------
# world -> gateway


class IntruderReport(Envelope):
    """The world reports an intruder appearing on (``on``) or leaving (``off``) ``cell``."""

    type: Literal["intruder"] = "intruder"
    cell: Cell
    state: Literal["on", "off"]


# --------------------------------------------------------------------------------------------
# gateway -> operator


class RobotView(_Model):
    """One robot in a snapshot."""

    robot_id: RobotId
    connected: bool
    cell: Cell
    heading: Heading | None = None
    activity: RobotActivity
    action_id: ActionId | None = None
    goal: Cell
    remaining: list[Cell] = Field(default_factory=list)
    slack_ms: float = 0.0
    task: int | None = None
    """Lifelong: the task the robot works on (None: none)."""
    errands: list[Cell] = Field(default_factory=list)
    """Lifelong: that task's errand cells still to reach, the next one first."""


class ActionCounts(_Model):
    """How many actions of the current plan are in each state."""

    pending: int = 0
    dispatched: int = 0
    running: int = 0
    blocked: int = 0
    finished: int = 0


class WaitEdge(_Model):
    """Robot ``robot`` waits, before its action ``action``, for ``for_robot``'s ``for_action``."""

    robot: RobotId
    action: int
    for_robot: RobotId
    for_action: int


class ReplanMark(_Model):
    """A replan of the current run: triggered at ``trigger_ms`` by ``policy``; plan ``plan``
    adopted at ``adopted_ms`` (both None while it is being solved, or if it was abandoned)."""

    trigger_ms: float
    policy: str
    plan: int | None = None
    adopted_ms: float | None = None


GatewayStatus = Literal["empty", "planning", "loaded", "running", "paused", "replanning", "done"]


class Snapshot(Envelope):
    """The whole fleet as the gateway sees it (on connect, on ``get_snapshot``)."""

    type: Literal["snapshot"] = "snapshot"
    t_ms: float
    status: GatewayStatus
    map_name: str = ""
    scen_name: str = ""
    """The scenario the instance was read from ("" when generated or given as a plan)."""
    rows: list[str] = Field(default_factory=list)
    plan: int | None = None
    paths: list[list[Cell]] = Field(default_factory=list)
    headings: list[list[PlanHeading]] = Field(default_factory=list)
    """Under the ``turning`` motion model each path's headings (one per cell), else empty."""
    robots: list[RobotView] = Field(default_factory=list)
    actions: ActionCounts = Field(default_factory=ActionCounts)
    fleet_slack: list[tuple[float, float]] = Field(default_factory=list)
    threshold_ms: float
    policy: PolicyName
    speed: float = 1.0
    soc_ms: float = 0.0
    makespan_ms: float = 0.0
    est_soc_ms: float = 0.0
    est_makespan_ms: float = 0.0
    waits: list[WaitEdge] = Field(default_factory=list)
    intruders: list[Cell] = Field(default_factory=list)
    replans: int = 0
    max_replans: int = 1
    """Replans allowed per run (operator's included): "replan now" is refused beyond it."""
    replan_marks: list[ReplanMark] = Field(default_factory=list)
    lifelong: bool = False
    """A lifelong shift: ``paths`` are the robots' committed steps from where they stand."""
    path_offsets: list[int] = Field(default_factory=list)
    """Lifelong: the action number of each path's first step (empty: all 0)."""
    worlds: int = 0
    """World connections (a simulator): without one, ``place_intruder`` is refused."""
    tasks_per_min: float | None = None
    """Lifelong: tasks finished per minute of the shift's plan time so far (the figure the
    terminal shows)."""
    period_ms: float | None = None
    """Lifelong: plan time between the planner's calls (a window each)."""


EventKind = Literal[
    "dispatch", "start", "finish", "blocked", "unblocked", "cancel", "refused", "plan", "trigger",
    "reschedule", "slack", "intruder", "summary", "status", "connection",
]


class Event(Envelope):
    """One entry of the operator event stream; mirrors the trace records of DESIGN section 3.

    Fields beyond ``event`` and ``t_ms`` are set as the kind needs: dispatch..cancel use
    plan/robot/action, refused too with the robot's ``reason``; plan uses plan/paths; trigger
    policy/fleet_slack_ms; reschedule plan/edges/switches/gain_ms (the plan's Type 2 edges
    from then on, ``[robot, action, robot2, action2]`` tail first; each switch as ``[cell,
    first, second]``: ``first`` now passes ``cell`` before ``second``); slack
    fleet_slack_ms; intruder cell/state; summary soc_ms/makespan_ms; status status;
    connection robot/state ("on"/"off"). A ``turning`` plan's event also has ``headings``.
    """

    type: Literal["event"] = "event"
    event: EventKind
    t_ms: float
    plan: int | None = None
    robot: RobotId | None = None
    action: int | None = None
    paths: list[list[Cell]] | None = None
    headings: list[list[PlanHeading]] | None = None
    policy: str | None = None
    fleet_slack_ms: float | None = None
    cell: Cell | None = None
    state: Literal["on", "off"] | None = None
    soc_ms: float | None = None
    makespan_ms: float | None = None
    status: GatewayStatus | None = None
    reason: str | None = None
    edges: list[tuple[RobotId, int, RobotId, int]] | None = None
    switches: list[tuple[Cell, RobotId, RobotId]] | None = None
    gain_ms: float | None = None


# --------------------------------------------------------------------------------------------
# unions

RobotMessage = (
    Hello | Ack | Started | Finished | Blocked | Unblocked | Cancelled | ActionRefused | State
)
"""What a robot may send."""

ToRobotMessage = Welcome | Action | CancelAction | Pause | Resume | Error
"""What the gateway sends a robot."""

OperatorCommand = (
    LoadInstance | LoadPlan | Start | Pause | Resume | ReplanNow | StopShift | SetPolicy
    | SetThreshold | SetSpeed | PlaceIntruder | GetSnapshot
)
"""What an operator may send."""

ToOperatorMessage = Snapshot | Event | Ok | Error
"""What the gateway sends an operator."""

WorldMessage = IntruderReport
"""What the "world" connection may send (it receives ``place_intruder`` and ``set_speed``)."""

AnyMessage = (
    Hello | Ack | Started | Finished | Blocked | Unblocked | Cancelled | ActionRefused | State
    | Welcome | Action | CancelAction | Pause | Resume | Error | Ok
    | LoadInstance | LoadPlan | Start | Pause | Resume | ReplanNow | StopShift | SetPolicy
    | SetThreshold | SetSpeed | PlaceIntruder | GetSnapshot
    | IntruderReport | Snapshot | Event
)

Message = Annotated[AnyMessage, Field(discriminator="type")]
"""Every message of the protocol (every version), discriminated on ``type``."""
