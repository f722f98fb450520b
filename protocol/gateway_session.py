"""The gateway's side of the protocol for one robot, as a sans-I/O state machine.

One :class:`GatewaySession` per robot lives across that robot's connections. The driver (the
gateway's engine) feeds it the robot's messages with the current plan time and the handle of
the connection they came on, the executor's dispatches and cancels, and hands back what
:meth:`GatewaySession.drain` returns, in order:

* :class:`ToRobot`: a message for the robot's current connection;
* :class:`Refuse`: an ``error`` reply to the sender of the message being handled;
* :class:`Report`: a robot event for the executor. The driver applies it and answers
  :meth:`GatewaySession.accepted` or :meth:`GatewaySession.rejected` (the bookkeeping changes
  only once the executor took the event, so a refused report changes nothing).

The rules, written once here:

* a robot speaks after its ``hello`` on the connection it said it on; a new ``hello`` replaces
  the old connection;
* ``hello`` catches up what the robot did while away: its ``finished`` ids (a missing
  ``started`` is applied first), its current action running or blocked, and the cancels it can
  no longer confirm (it no longer holds the action); then the driver asks for the ``welcome``;
* the ``welcome`` resends, in index order, ONLY the dispatched actions the robot does not hold:
  those neither acknowledged in its ``hello`` (``acked``, ``current``) nor finished. An action
  acknowledged on an earlier connection but missing from the ``hello`` was lost by the robot (a
  restart) and is resent too. Cancels still owed for actions the robot holds follow the
  welcome as ``cancel`` messages, and so do cancels of the actions the robot says it holds
  but the gateway does not stand behind (never dispatched in this run, e.g. after a restart
  that started a fresh run); their ``cancelled`` confirmations are taken silently;
* each ``ack`` is recorded; an ``ack`` of an action never dispatched is refused
  (``unknown_action``). A protocol v3 robot sends none (its first report about an action
  acknowledges it); what the gateway resends never depended on the ``ack`` (the ``hello``
  says what the robot holds), only which refusals it still owes (below);
* a report about an applied action is a ``duplicate`` (a completion reported twice is applied
  once; a session remembers the latest :data:`APPLIED_KEEP` applied actions), a report about
  an action never dispatched (or of an earlier plan: REPORT-3) is ``unknown_action``, a
  repeated ``started`` / ``blocked`` is a ``duplicate``; everything else goes to the executor,
  which may still reject it (``rejected``);
* protocol v2 (the version of the robot's ``hello``): a ``blocked`` of a move under way is a
  stop on the way (a bumper), told to the executor as ``stopped``; its ``unblocked`` resumes
  the move. A ``refused`` action that has not started goes to the executor as ``refused``
  (with the robot's reason); once taken, it and the actions dispatched to the robot after it
  (of that plan, or of a lifelong shift's later segments) are no longer held, and a repeated,
  ``queued_behind`` or ``pose_mismatch`` refusal of them is dropped silently, also when it
  arrives after they were dispatched again (the robot had not answered them yet: its answer
  is about the old dispatch). Which ones the robot still answers: in v1 and v2 those it had
  not acknowledged (it drops acknowledged ones silently); in v3 all of them (it answers every
  action it drops with a refusal, queued ones included).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Literal

from protocol.messages import (
    FOLDED_ACK,
    PROTOCOL_VERSION,
    Action,
    CancelAction,
    ErrorCode,
    Hello,
    Pause,
    Pose,
    ProtocolVersion,
    Resume,
    RobotActivity,
    ToRobotMessage,
    Welcome,
    action_run,
    parse_action_id,
)

ReportKind = Literal["started", "finished", "blocked", "unblocked", "cancelled", "refused"]
"""What a robot reports."""
ExecutorEvent = Literal["started", "finished", "blocked", "stopped", "unblocked", "cancelled",
                        "refused"]
"""What the executor is told: a v2 robot's ``blocked`` of a move under way is ``stopped``."""
Phase = Literal["dispatched", "running", "blocked"]
Pending = Literal["held", "running", "finished"]
"""What a robot said of an action the gateway has not dispatched (yet)."""
APPLIED_KEEP = 512
"""Applied actions a session remembers per robot (the latest): twice what one ``hello`` can
list as finished, so a reconnecting robot's catch-up and any late repeat of a recent report
are still recognised (``duplicate``); an older repeat is an ``unknown_action``. Either way it
changes nothing, and a lifelong shift's sessions stay bounded."""


@dataclass(slots=True)  # not frozen (4x cheaper to build): one per message
class ToRobot:
    """Send a message of type ``kind`` with ``fields`` on the robot's current connection."""

    kind: type[ToRobotMessage]
    fields: dict[str, Any]


@dataclass(slots=True)  # not frozen (4x cheaper to build): one per message
class Refuse:
    """Reply ``error(code, ref, detail)`` to the sender of the message being handled."""

    code: ErrorCode
    ref: str | None
    detail: str


@dataclass(slots=True)  # not frozen (4x cheaper to build): one per message
class Report:
    """Robot ``robot`` reports ``kind`` of action ``index`` of plan ``plan`` at ``t_ms``;
    ``ref`` is the report's msg_id (None for what a ``hello`` caught up); ``reason`` the
    robot's words for a refusal."""

    kind: ExecutorEvent
    robot: int
    plan: int
    index: int
    action_id: str
    t_ms: float
    ref: str | None
    reason: str = ""


GatewayEffect = ToRobot | Refuse | Report
"""What :meth:`GatewaySession.drain` hands to the driver."""


def hello_refusal(msg: Hello, turning_plan: bool) -> str | None:
    """Why a robot's hello is refused before it gets a session (then the driver answers
    ``unsupported_version`` and closes the connection with 1008), or None: a protocol v1 robot
    moves omni-directionally, so it cannot execute a plan for turning robots."""
    if msg.v < 2 and turning_plan:
        return ("the plan is for turning robots: protocol v2 needed (a v1 robot moves "
                "omni-directionally)")
    return None


@dataclass
class Held:
    """An action the robot holds: dispatched, not finished or cancelled."""

    fields: dict[str, Any]
    phase: Phase = "dispatched"
    acked: bool = False
    cancel: bool = False
    moved: bool = False
    """It started (a later ``blocked`` / ``unblocked`` is a stop on the way and its end)."""


@dataclass
class GatewaySession:
    """What the gateway knows about one robot, and its protocol rules (see module doc)."""

    robot_id: int
    link: object | None = None
    """The driver's handle of the connection the robot said ``hello`` on (None: offline)."""
    pose: Pose | None = None
    version: int = PROTOCOL_VERSION
    """The protocol version of the robot's latest ``hello``."""
    held: dict[str, Held] = field(default_factory=dict)
    applied: dict[str, str] = field(default_factory=dict)
    """Action id -> "finished" / "cancelled" / "refused", for the current plan: the latest
    :data:`APPLIED_KEEP` (in the order they were applied)."""
    next_index: int = 0
    """Actions of the current plan finished."""
    disowned: set[str] = field(default_factory=set)
    """Actions the robot said it holds that the gateway does not stand behind (of another run
    or plan): the welcome's ``drop`` (the robot MUST NOT start them), then cancelled."""
    pending: dict[str, tuple[Pending, float]] = field(default_factory=dict)
    """Actions of the run the robot said it holds, runs or finished (and when) that the
    gateway has not dispatched: its journal lost their dispatch. Taken as acknowledged, and
    their start and finish applied, when the executor dispatches them again; reports about them
    meanwhile are kept, not refused (a robot need not repeat a ``finished``: DUP-1)."""
    owed: set[str] = field(default_factory=set)
    """Actions taken back with a refusal of an earlier one before the robot answered them:
    it will refuse them too, and that refusal is about the old dispatch even if it arrives
    after the action was dispatched again (until the next ``hello``)."""
    _out: list[GatewayEffect] = field(default_factory=list)

    # ------------------------------------------------------------------ state
    @property
    def connected(self) -> bool:
        """Whether the robot is on a live connection."""
        return self.link is not None

    def activity(self) -> RobotActivity:
        """What the robot is doing, as far as the gateway knows."""
        if self.link is None:
            return "disconnected"
        for h in self.held.values():
            return "received" if h.phase == "dispatched" else h.phase
        return "idle"

    def new_run(self) -> None:
        """Forget the actions of the previous run."""
        self.held.clear()
        self.applied.clear()
        self.disowned.clear()
        self.pending.clear()
        self.owed.clear()
        self.next_index = 0

    def drain(self) -> list[GatewayEffect]:
        """What the driver must do, in order, since the last call (then forgotten)."""
        out, self._out = self._out, []
        return out

    # ------------------------------------------------------------------ connections
    def hello(self, msg: Hello, t_ms: float, *, run: str | None = None,
              plan: int | None = None) -> None:
        """The robot said hello (on a new connection): queue the catch-up reports. The driver
        applies them, routes what the executor dispatches (:meth:`dispatch`, held for the
        resend), then calls :meth:`welcome` with the connection. ``run`` is the run being
        executed (None: none) and ``plan`` its plan (None: any plan of the run, a lifelong
        shift's segments): an action of theirs that the robot holds or finished but that the
        gateway has not dispatched (a journal that lost its last records) is :attr:`pending`,
        any other one it holds is :attr:`disowned` (the welcome's ``drop``)."""
        self.link = None
        self.version = msg.v
        self.owed.clear()  # what was in flight on the old connection is gone
        if msg.pose is not None:
            self.pose = msg.pose
        holds = set(msg.acked)
        current = msg.current
        if current is not None:
            holds.add(current.action_id)
        for aid in msg.finished:
            h = self.held.get(aid)
            if h is not None:
                if h.phase != "running":
                    self._report("started", aid, t_ms, None)
                self._report("finished", aid, t_ms, None)
        if current is not None and current.action_id in self.held:
            h = self.held[current.action_id]
            if current.state == "running" and h.phase != "running":
                self._report("started", current.action_id, t_ms, None)
            elif current.state == "blocked" and h.phase == "dispatched":
                self._report("blocked", current.action_id, t_ms, None)
        finished = set(msg.finished)
        running = current.action_id if current is not None and current.state == "running" \
            else None
        self.pending, self.disowned = {}, set()
        for aid in [*msg.finished, *sorted(holds)]:
            if aid in self.held or aid in self.applied:
                continue
            if self._ours(aid, run, plan):
                state: Pending = "finished" if aid in finished else (
                    "running" if aid == running else "held")
                self.pending[aid] = (state, t_ms)
            elif aid in holds:
                self.disowned.add(aid)
        for aid, h in self.held.items():
            if aid in finished:
                continue
            if aid in holds:
                h.acked = True
            elif h.cancel and h.phase != "running":
                self._report("cancelled", aid, t_ms, None)  # nothing left to confirm it
            else:
                h.acked = False  # resent: it was never received, or was lost

    def _ours(self, aid: str, run: str | None, plan: int | None) -> bool:
        """Whether ``aid`` is an action of this robot in ``run`` (and ``plan``, if given)."""
        if run is None:
            return False
        try:
            p, robot, _ = parse_action_id(aid)
            return action_run(aid) == run and robot == self.robot_id and plan in (None, p)
        except ValueError:
            return False

    def welcome(self, link: object, *, version: ProtocolVersion, start: Pose | None,
                plan: int | None, state_period_ms: float, paused: bool) -> int:
        """Welcome the robot on ``link`` (speaking ``version``): resend what it does not hold,
        then the cancels it owes. Returns how many actions were resent."""
        self.link = link
        resend = [Action(v=version, msg_id=f"resend-{aid}", seq=0, **h.fields)
                  for aid, h in self.held.items() if not h.acked and not h.cancel]
        self._send(Welcome, robot_id=self.robot_id, start=start, plan=plan, resend=resend,
                   drop=sorted(self.disowned), state_period_ms=state_period_ms, paused=paused)
        for aid, h in self.held.items():
            if h.cancel:
                self._send(CancelAction, action_id=aid)
        for aid in sorted(self.disowned):
            self._send(CancelAction, action_id=aid)
        return len(resend)

    def disconnected(self, link: object) -> bool:
        """Connection ``link`` closed; True if it was the robot's current one."""
        if self.link is not link or link is None:
            return False
        self.link = None
        return True

    # ------------------------------------------------------------------ from the robot
    def ack(self, aid: str, ref: str, link: object) -> None:
        """The robot acknowledged action ``aid``."""
        if not self._linked(link, ref):
            return
        self.owed.discard(aid)  # it took the action after all
        h = self.held.get(aid)
        if h is not None:
            h.acked = True
        elif aid not in self.applied and aid not in self.pending:
            self._refuse(ErrorCode.UNKNOWN_ACTION, ref,
                         f"action {aid} was never dispatched to robot {self.robot_id}")

    def report(self, kind: ReportKind, aid: str, ref: str, link: object, t_ms: float,
               pose: Pose | None = None, reason: str = "") -> None:
        """A ``started`` / ``finished`` / ``blocked`` / ``unblocked`` / ``cancelled`` /
        ``refused`` (``reason``) report."""
        if not self._linked(link, ref):
            return
        if pose is not None:
            self.pose = pose
        if kind == "refused" and (self.applied.get(aid) == "refused" or aid in self.owed):
            self.owed.discard(aid)
            return  # taken back already (a refusal of an earlier action covered it)
        if self.owed and kind in ("started", "blocked"):  # (v3: it took the action after all)
            self.owed.discard(aid)
        if kind == "cancelled" and aid in self.disowned:
            self.disowned.discard(aid)  # the robot dropped what the gateway disowned
            return
        if aid in self.pending:  # kept until the executor dispatches it again
            if kind in ("started", "finished"):
                self.pending[aid] = ("running" if kind == "started" else "finished", t_ms)
            return
        if aid in self.applied:
            self._refuse(ErrorCode.DUPLICATE, ref,
                         f"{kind} of {aid}: the action was already {self.applied[aid]}")
            return
        h = self.held.get(aid)
        if h is None:
            self._refuse(ErrorCode.UNKNOWN_ACTION, ref,
                         f"{kind} of {aid}: never dispatched to robot {self.robot_id}")
            return
        if (kind, h.phase) in (("started", "running"), ("blocked", "blocked")):
            self._refuse(ErrorCode.DUPLICATE, ref, f"{aid} is already {h.phase}")
            return
        if kind == "blocked" and h.phase == "running" and self.version >= 2:
            self._report("stopped", aid, t_ms, ref)
        else:
            self._report(kind, aid, t_ms, ref, reason)

    def state(self, pose: Pose | None, link: object) -> None:
        """A periodic ``state``: only the pose is kept."""
        if link is self.link and link is not None and pose is not None:
            self.pose = pose

    def accepted(self, r: Report) -> None:
        """The executor took report ``r``: update the bookkeeping."""
        h = self.held.get(r.action_id)
        if h is None:
            return
        if r.kind == "started":
            h.phase, h.moved = "running", True
        elif r.kind in ("blocked", "stopped"):
            h.phase = "blocked"
        elif r.kind == "unblocked":
            h.phase = "running" if h.moved else "dispatched"
        elif r.kind == "refused":  # the executor took back this action and the later ones
            answers_all = self.version >= FOLDED_ACK  # a v3 robot answers each one it drops
            for aid in [a for a in self.held if self._taken_back_with(a, r)]:
                if aid != r.action_id and (answers_all or not self.held[aid].acked):
                    self.owed.add(aid)
                del self.held[aid]
                self._applied(aid, "refused")
        else:
            del self.held[r.action_id]
            self._applied(r.action_id, r.kind)
            if r.kind == "finished":
                self.next_index = max(self.next_index, r.index + 1)

    def _applied(self, aid: str, kind: str) -> None:
        """Remember that ``aid`` ended as ``kind``; forget the oldest beyond the bound."""
        applied = self.applied
        applied[aid] = kind
        while len(applied) > APPLIED_KEEP:
            del applied[next(iter(applied))]

    def rejected(self, r: Report, reason: str) -> None:
        """The executor refused report ``r`` (nothing changes; the sender is told)."""
        if r.ref is not None:
            self._refuse(ErrorCode.REJECTED, r.ref, reason)

    # ------------------------------------------------------------------ from the executor
    def dispatch(self, fields: dict[str, Any]) -> None:
        """The executor released an action (``fields`` of an ``action`` message); it is sent
        now if the robot is online, else in the next welcome."""
        aid = fields["action_id"]
        h = self.held[aid] = Held(fields)
        self.applied.pop(aid, None)  # dispatched again (an abandoned replan)
        said = self.pending.pop(aid, None)
        if said is not None:  # the robot has it already (a dispatch the journal lost)
            state, t_ms = said
            h.acked = True
            if state != "held":
                self._report("started", aid, t_ms, None)
            if state == "finished":
                self._report("finished", aid, t_ms, None)
        elif self.link is not None:
            self._out.append(ToRobot(Action, fields))  # (as they are: no copy per dispatch)

    def cancel(self, aid: str) -> None:
        """The executor cancels ``aid`` (a replan): tell the robot if it is online; a robot
        that is not owes the confirmation at its next hello."""
        h = self.held.get(aid)
        if h is not None:
            h.cancel = True
        if self.link is not None:
            self._send(CancelAction, action_id=aid)

    def set_paused(self, paused: bool) -> None:
        """The operator paused (or resumed) the fleet: tell the robot if it is online."""
        if self.link is not None:
            if paused:
                self._send(Pause, reason="operator")
            else:
                self._send(Resume)

    def plan_adopted(self) -> None:
        """A new plan starts from index 0. The earlier plans' actions are forgotten (before
        a replan every one of them finished or was cancelled, so a late report about one is
        an unknown action): a session remembers one plan, as a compacted journal does."""
        self.next_index = 0
        self.applied.clear()
        self.pending.clear()

    # ------------------------------------------------------------------ helpers
    def _linked(self, link: object, ref: str) -> bool:
        if link is None or link is not self.link:
            self._refuse(ErrorCode.BAD_STATE, ref, "say hello first")
            return False
        return True

    def _report(self, kind: ExecutorEvent, aid: str, t_ms: float, ref: str | None,
                reason: str = "") -> None:
        plan, _, index = parse_action_id(aid)
        self._out.append(Report(kind, self.robot_id, plan, index, aid, t_ms, ref, reason))

    @staticmethod
    def _taken_back_with(aid: str, r: Report) -> bool:
        """Whether the refusal ``r`` also takes back held action ``aid``: dispatched after it
        in the same run (its plan, or a later one: a lifelong shift's later segments, whose
        action numbers go on), not before it."""
        plan, _, index = parse_action_id(aid)
        return (action_run(aid) == action_run(r.action_id) and plan >= r.plan
                and index >= r.index)

    def _refuse(self, code: ErrorCode, ref: str | None, detail: str) -> None:
        self._out.append(Refuse(code, ref, detail))

    def _send(self, kind: type[ToRobotMessage], **fields: Any) -> None:
        self._out.append(ToRobot(kind, fields))
