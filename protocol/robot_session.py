"""The robot's side of the protocol as a sans-I/O state machine (no I/O, no clock, no asyncio).

A driver (the real robot's :mod:`robot_client.client`, the simulated robots of
:mod:`sim_clients.fleet`) owns the link and the body. It tells the session when a link is up
(:meth:`RobotSession.connected`) or gone (:meth:`RobotSession.disconnected`), feeds it every
message from the gateway (:meth:`RobotSession.receive`) and every report of the body
(:meth:`RobotSession.report`), asks it for the next action to execute
(:meth:`RobotSession.take`), and sends / carries out what :meth:`RobotSession.drain` returns, in
order. The rules, written once here for every robot:

* ``hello`` on every new link: pose, the actions held (acknowledged, not finished), the recent
  finishes (:data:`HISTORY` of them: their reports may have been lost) and the current activity;
* every ``action`` is acknowledged (protocol v1 and v2: with an ``ack`` at once; v3,
  :data:`~protocol.messages.FOLDED_ACK`: by the first report about it, ``started`` or
  ``blocked`` when it is taken up, or its ``cancelled``, so a v3 robot sends two messages per
  action instead of three), unless the robot refuses it (protocol v2 ``refused``): its ``src``
  is not the pose the robot will stand on when the action is due (its own pose, or the ``dst``
  of the last action it holds; a heading counts when both have one) or ``check`` fails; every
  later action of the same plan is then refused too (``queued_behind``), and
  :meth:`RobotSession.refuse_current` refuses an action the body finds it cannot start when it
  is due (the actions queued behind it are dropped with it: silently in v1 and v2, whose
  ``ack`` told the gateway they were held; in v3 each with ``refused`` ``queued_behind``, so
  every action a v3 robot receives gets exactly one first answer); a duplicate (held, current
  or recently finished) is acknowledged again in v1 and v2 (in v3 it gets nothing) but never
  executed twice, and a duplicate of a finished action gets its ``finished`` again (the
  gateway resends an action only if it has no finish for it);
* actions are held in a queue and executed strictly in index order, one after the other, and
  only while the robot is welcomed on a live link and not paused (on link loss the current
  action completes, nothing new starts);
* ``cancel`` of a queued action drops it and every action queued behind it (they cannot run
  without it), each confirmed with ``cancelled`` and forgotten (an abandoned replan may
  dispatch it again); ``cancel`` of the current action drops it only while it is ``blocked``:
  waiting for its cell (confirmed at once) or stopped on the way (protocol v2, a bumper: the
  body goes back to the action's source, then :meth:`RobotSession.aborted` confirms); a moving
  robot finishes; a cancel of anything else is stale and ignored;
* ``pause`` / ``resume`` stop and allow new starts (a running move completes);
* a v3 robot whose ``hello`` a gateway refuses as ``unsupported_version`` (one that predates
  v3) says ``hello`` again in v2 and speaks v2 from then on;
* reports (``started``, ``finished``, ``blocked``, ``unblocked``) are sent while a link is up;
  what a link loss swallows is carried by the next ``hello``. A ``blocked`` after ``started``
  is a stop on the way (protocol v2, a bumper): ``unblocked`` makes the action run again.
"""

from __future__ import annotations

import itertools
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Literal, TypeVar

from protocol.messages import (
    FOLDED_ACK,
    PROTOCOL_VERSION,
    Ack,
    Action,
    ActionRefused,
    Activity,
    AnyMessage,
    Blocked,
    CancelAction,
    Cancelled,
    Error,
    ErrorCode,
    Finished,
    Hello,
    Pause,
    Pose,
    ProtocolVersion,
    RefuseCode,
    Resume,
    RobotActivity,
    RobotMessage,
    Started,
    State,
    Unblocked,
    Welcome,
    parse_action_id,
    plan_key,
)

HISTORY = 256
"""How many finished action ids a robot remembers (for ``hello`` and duplicate detection); the
longest list a ``hello`` may carry."""

ReportKind = Literal["started", "finished", "blocked", "unblocked"]
REPORTS: dict[str, type[Started | Finished | Blocked | Unblocked | Cancelled]] = {
    "started": Started, "finished": Finished, "blocked": Blocked, "unblocked": Unblocked,
    "cancelled": Cancelled}
"""The message of each report kind a robot sends."""

M = TypeVar("M", bound=AnyMessage)


@dataclass(frozen=True, slots=True)
class Send:
    """Send ``message`` to the gateway (in the order drained)."""

    message: RobotMessage


@dataclass(frozen=True, slots=True)
class Abort:
    """The body must drop its current action ``action_id``. If it has not ``moved`` (it waits
    for its cell) the session already confirmed it with ``cancelled``; if it ``moved`` (a move
    stopped on the way) the body goes back to the action's source and then calls
    :meth:`RobotSession.aborted`, which confirms."""

    action_id: str
    moved: bool = False


@dataclass(frozen=True, slots=True)
class Welcomed:
    """The gateway welcomed the robot on this link."""

    welcome: Welcome


@dataclass(frozen=True, slots=True)
class Received:
    """An action arrived; ``duplicate`` if the robot held or finished it already."""

    action: Action
    duplicate: bool


@dataclass(frozen=True, slots=True)
class Refused:
    """The robot refused an action (``reason``; ``refused`` was sent): not acknowledged, not
    held."""

    action: Action
    reason: str


@dataclass(frozen=True, slots=True)
class GatewayError:
    """The gateway refused one of the robot's messages."""

    error: Error


RobotEffect = Send | Abort | Welcomed | Received | Refused | GatewayError
"""What :meth:`RobotSession.drain` hands to the driver."""


class RobotSession:
    """One robot's protocol state across links (see module doc).

    ``check`` may refuse an action the body cannot execute (raise ValueError with the reason);
    an action that does not start where the robot will stand is refused in any case.
    Messages get ``msg_id`` ``"<msg_prefix><n>"`` (``n`` counts every message of the session,
    so ids stay unique across links) and ``seq`` counting from 0 on each link; every message
    is of protocol ``version`` (default the latest: no ``ack``).
    """

    def __init__(self, robot_id: int, *, msg_prefix: str | None = None,
                 check: Callable[[Action], None] | None = None,
                 repeat_finished: bool = True,
                 version: ProtocolVersion = PROTOCOL_VERSION) -> None:
        self.robot_id = robot_id
        self.version: ProtocolVersion = version
        self._acks = version < FOLDED_ACK
        """Acknowledge each action with an ``ack`` (v1, v2); v3 folds it into the reports."""
        self.repeat_finished = repeat_finished
        """Send ``finished`` again for a duplicate of a finished action (a MAY of DUP-1; a robot
        that implements only the MUST rules does not)."""
        self.pose: Pose | None = None
        """The latest pose the driver gave (sent in messages that need one)."""
        self.link_up = False
        self.welcomed = False
        """Welcomed on the current link (actions start only then)."""
        self.paused = False
        self.state_period_ms = 5000.0
        self.welcomes = 0
        self.duplicates = 0
        self.queue: deque[Action] = deque()
        """Actions acknowledged and not started, in index order."""
        self.current: str | None = None
        """The action taken by the body and not finished (or dropped)."""
        self._current_action: Action | None = None
        self._refused: tuple[str, int] | None = None  # (plan_key, index) of the last refusal
        self.phase: Literal["received", "running", "blocked"] = "received"
        self._moved = False  # the current action started (a later blocked is a stop on the way)
        self._aborting = False  # the current action was cancelled on the way; going back
        self._finished: dict[str, None] = {}  # insertion-ordered, at most HISTORY
        self._queued: set[str] = set()
        self._check = check
        self._prefix = msg_prefix if msg_prefix is not None else f"r{robot_id}-"
        self._ids = itertools.count()
        self._hello_id: str | None = None  # the msg_id of the latest hello
        self._seq = 0
        self._out: list[RobotEffect] = []

    # ------------------------------------------------------------------ what it holds
    @property
    def finished(self) -> list[str]:
        """The recently finished action ids, oldest first (at most :data:`HISTORY`)."""
        return list(self._finished)

    def knows(self, action_id: str) -> bool:
        """Whether ``action_id`` is held, current or recently finished (a duplicate)."""
        return (action_id in self._queued or action_id == self.current
                or action_id in self._finished)

    def activity(self) -> Activity | None:
        """The action the robot holds and what it does with it."""
        if self.current is not None:
            return Activity(action_id=self.current, state=self.phase)
        if self.queue:
            return Activity(action_id=self.queue[0].action_id, state="received")
        return None

    def reset(self) -> None:
        """Forget every action (a new run starts from scratch); the link stays as it is."""
        self.queue.clear()
        self._queued.clear()
        self._finished.clear()
        self.current, self._current_action, self._refused = None, None, None
        self.phase = "received"
        self._aborting = False

    # ------------------------------------------------------------------ link
    def connected(self, pose: Pose | None = None) -> None:
        """A new link is up: say ``hello`` with a snapshot of what the robot holds and did."""
        if pose is not None:
            self.pose = pose
        self.link_up, self.welcomed, self._seq = True, False, 0
        self._hello()

    def _hello(self) -> None:
        held = [a.action_id for a in self.queue]
        if self.current is not None:
            held.insert(0, self.current)
        self._send(Hello, robot_id=self.robot_id, pose=self.pose, acked=held[-HISTORY:],
                   finished=list(self._finished), current=self.activity())
        sent = self._out[-1] if self._out else None
        self._hello_id = sent.message.msg_id if isinstance(sent, Send) else None

    def disconnected(self) -> None:
        """The link is gone: nothing is sent and nothing new starts until the next welcome."""
        self.link_up = self.welcomed = False

    # ------------------------------------------------------------------ from the gateway
    def receive(self, msg: AnyMessage) -> None:
        """Handle one message from the gateway."""
        if isinstance(msg, Action):
            self._action(msg)
        elif isinstance(msg, CancelAction):
            self._cancel(msg.action_id)
        elif isinstance(msg, Welcome):
            self.welcomed = self.link_up
            self.welcomes += 1
            self.paused = msg.paused
            self.state_period_ms = msg.state_period_ms
            self._out.append(Welcomed(msg))
            for aid in msg.drop:  # before anything can start: the gateway disowns them
                self._cancel(aid)
            for action in msg.resend:
                self._action(action)
        elif isinstance(msg, Pause):
            self.paused = True
        elif isinstance(msg, Resume):
            self.paused = False
        elif isinstance(msg, Error):
            if (msg.code is ErrorCode.UNSUPPORTED_VERSION and msg.ref == self._hello_id
                    and not self.welcomed and self.version >= FOLDED_ACK):
                self.version, self._acks = 2, True  # a gateway that predates v3: speak v2
                self._hello()
                return
            self._out.append(GatewayError(msg))

    def _action(self, msg: Action) -> None:
        aid = msg.action_id
        if self.knows(aid):
            self.duplicates += 1
            self._out.append(Received(msg, True))
            if self._acks:
                self._send(Ack, action_id=aid)
            if aid in self._finished and self.repeat_finished:
                self._send(Finished, action_id=aid, pose=self.pose)
            return
        refusal = self._refusal(msg)
        if refusal is not None:
            self._refuse(msg, *refusal)
            return
        self.queue.append(msg)
        self._queued.add(aid)
        self._out.append(Received(msg, False))
        if self._acks:
            self._send(Ack, action_id=aid)

    def _refusal(self, msg: Action) -> tuple[RefuseCode, str] | None:
        """Why the robot refuses ``msg`` (None: it takes it)."""
        key, index = plan_key(msg.action_id), parse_action_id(msg.action_id)[2]
        if self._refused is not None:
            refused_key, refused_index = self._refused
            if key == refused_key and index > refused_index:
                return "queued_behind", (f"action {refused_key}.{refused_index} before it was "
                                         "refused")
            self._refused = None  # a new plan, or the refused action dispatched again
        due = self.queue[-1].dst if self.queue else (
            self._current_action.dst if self._current_action is not None else self.pose)
        src = msg.src
        if due is not None and (tuple(src.cell) != tuple(due.cell) or (
                None not in (src.heading, due.heading) and src.heading != due.heading)):
            return "pose_mismatch", (f"it starts at {_pose_text(src)}, but the robot will "
                                     f"stand at {_pose_text(due)}")
        if self._check is not None:
            try:
                self._check(msg)
            except ValueError as exc:
                return "cannot_execute", str(exc)
        return None

    def _refuse(self, msg: Action, code: RefuseCode, detail: str) -> None:
        if code != "queued_behind":  # the first refused action stays the one that clears it
            self._refused = (plan_key(msg.action_id), parse_action_id(msg.action_id)[2])
        self._out.append(Refused(msg, detail))
        self._send(ActionRefused, action_id=msg.action_id, pose=self.pose, code=code,
                   detail=detail[:500])

    def refuse_current(self, code: RefuseCode, detail: str, pose: Pose | None = None) -> None:
        """The body cannot start the current action now that it is due (e.g. it does not hold
        the action's start heading): refuse it; the actions queued behind it are dropped too
        (the gateway takes them back with it)."""
        if pose is not None:
            self.pose = pose
        action = self._current_action
        if action is None or self._moved:
            return
        self.current, self._current_action, self.phase = None, None, "received"
        behind = list(self.queue)
        self.queue.clear()
        self._queued.clear()
        self._refuse(action, code, detail)
        if not self._acks:  # v3: no ack told the gateway these were held; answer each
            why = f"action {action.action_id} before it was refused"
            for queued in behind:
                self._send(ActionRefused, action_id=queued.action_id, pose=self.pose,
                           code="queued_behind", detail=why)

    def _cancel(self, aid: str) -> None:
        if aid in self._queued:
            ids = [a.action_id for a in self.queue]
            self._drop_queue(ids.index(aid))
        elif aid == self.current and self.phase == "blocked" and not self._aborting:
            self._out.append(Abort(aid, self._moved))
            if self._moved:
                self._aborting = True  # confirmed by aborted() once back on the source
            else:
                self.current, self._current_action = None, None
                self._confirm(aid)
            self._drop_queue(0)

    def aborted(self, action_id: str, pose: Pose | None = None) -> None:
        """The body is back on the source of ``action_id``, a move stopped on the way that a
        ``cancel`` aborted (:class:`Abort` with ``moved``): confirm it with ``cancelled``."""
        if pose is not None:
            self.pose = pose
        if action_id == self.current and self._aborting:
            if self._current_action is not None:
                self.pose = self._current_action.src if pose is None else pose
            self.current, self.phase, self._aborting = None, "received", False
            self._current_action = None
            self._confirm(action_id)

    def _drop_queue(self, first: int) -> None:
        """Drop the queued actions from position ``first`` on, each confirmed."""
        dropped = [self.queue.pop().action_id for _ in range(len(self.queue) - first)]
        for aid in reversed(dropped):
            self._queued.discard(aid)
            self._confirm(aid)

    def _confirm(self, aid: str) -> None:
        self._send(Cancelled, action_id=aid, pose=self.pose)

    # ------------------------------------------------------------------ from the body
    def take(self) -> Action | None:
        """The next action for an idle body, if it may start one now (welcomed on a live
        link, not paused, nothing current); it becomes the current action."""
        if (self.current is not None or not self.queue or not self.welcomed
                or self.paused):
            return None
        action = self.queue.popleft()
        self._queued.discard(action.action_id)
        self.current, self.phase, self._moved = action.action_id, "received", False
        self._current_action, self._aborting = action, False
        return action

    def report(self, kind: ReportKind, action_id: str, pose: Pose | None = None) -> None:
        """The body reports ``kind`` about its current action (sent if a link is up)."""
        if pose is not None:
            self.pose = pose
        if kind == "finished":
            if action_id == self.current:
                if pose is None and self._current_action is not None:
                    self.pose = self._current_action.dst
                self.current, self._current_action = None, None
            self._finished[action_id] = None
            if len(self._finished) > HISTORY:
                del self._finished[next(iter(self._finished))]
        elif action_id == self.current:
            self._moved = self._moved or kind == "started"
            self.phase = "blocked" if kind == "blocked" else (
                "running" if self._moved else "received")
        self._send(REPORTS[kind], action_id=action_id, pose=self.pose)

    def state(self, pose: Pose | None = None, *, battery: float | None = None,
              held_up: bool = False) -> None:
        """Send a ``state`` snapshot; ``held_up``: the current move is paused by the body (a
        bumper), reported as activity ``blocked``."""
        if pose is not None:
            self.pose = pose
        current = self.activity()
        if held_up and self.current is not None:
            current = Activity(action_id=self.current, state="blocked")
        activity: RobotActivity = current.state if current is not None else (
            "paused" if self.paused else "idle")
        self._send(State, robot_id=self.robot_id, pose=self.pose, activity=activity,
                   current=current, battery=battery)

    # ------------------------------------------------------------------ effects
    def _send(self, kind: type[M], **fields: Any) -> None:
        """Queue a message if a link is up. Built without validating again (every field comes
        from validated values), which halves a simulated robot's cost per message."""
        if not self.link_up:
            return
        n = next(self._ids)
        message = kind.model_construct(v=self.version, msg_id=f"{self._prefix}{n}",
                                       seq=self._seq, **fields)
        self._seq += 1
        self._out.append(Send(message))  # type: ignore[arg-type]

    def drain(self) -> list[RobotEffect]:
        """What the driver must do, in order, since the last call (then forgotten)."""
        out, self._out = self._out, []
        return out


def _pose_text(pose: Pose) -> str:
    cell = f"[{pose.cell[0]}, {pose.cell[1]}]"
    return cell if pose.heading is None else f"{cell} facing {pose.heading}"
