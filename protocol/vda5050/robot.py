"""The fleetgate protocol's robot side for one VDA 5050 vehicle, as a sans-I/O state machine:
the gateway sees a robot like any other (hello, ack, started, finished, blocked, unblocked,
cancelled, refused, state) while :class:`protocol.vda5050.master.VehicleMaster` drives the
vehicle.

* ``hello`` on every new gateway link: the vehicle's pose (from its last ``state``), the
  actions released to it and not finished (``acked``), the recent finishes, and the current
  one;
* an ``action`` is acknowledged and released to the vehicle (an order or an order update;
  the actions that arrived together, up to :meth:`VdaRobot.commit`, in one message): the
  actions a gateway releases ahead (lookahead) extend the vehicle's base. A duplicate is
  acknowledged again (and its ``finished`` sent again if it finished), never released twice.
  An action that does not start where the vehicle will stand is refused (``pose_mismatch``),
  and every later action of that plan with it (``queued_behind``);
* ``cancel`` goes to the master (``cancelOrder``); the vehicle's answer becomes ``cancelled``
  (or ``finished``, if it got there first);
* ``pause`` / ``resume`` become ``startPause`` / ``stopPause``;
* the master's reports become the matching messages.

It speaks protocol v2 (an ``ack`` per action; a vehicle's refusal drops only the refused
action, not the ones released behind it, so it does not answer each as protocol v3 asks).
"""

from __future__ import annotations

import itertools
from collections.abc import Callable
from typing import Any

from protocol.messages import (
    Ack,
    Action,
    ActionRefused,
    Activity,
    AnyMessage,
    CancelAction,
    Finished,
    Hello,
    Pause,
    Pose,
    Resume,
    RobotActivity,
    RobotMessage,
    State,
    Welcome,
    parse_action_id,
    plan_key,
)
from protocol.robot_session import HISTORY, REPORTS
from protocol.vda5050.master import Effect, Report, VehicleMaster
from protocol.vda5050.nodes import heading_of


class VdaRobot:
    """One VDA 5050 vehicle as robot ``robot_id`` of the gateway (see the module docstring).

    ``turning``: plans carry headings (the pose reports the vehicle's heading).
    ``plan_of(action)``: all actions of the robot's plan that ``action`` belongs to (the
    orders' horizon is the part not released yet); without it orders have no horizon."""

    def __init__(self, robot_id: int, master: VehicleMaster, *, turning: bool,
                 plan_of: Callable[[Action], list[Action]] | None = None) -> None:
        self.robot_id = robot_id
        self.master = master
        self.turning = turning
        self.plan_of = plan_of
        self._plan_key: str | None = None
        self.link_up = False
        self.paused = False
        self.held: dict[str, Action] = {}
        """Released to the vehicle and not finished, in index order."""
        self.phase: dict[str, str] = {}
        self._finished: dict[str, None] = {}
        self._refused: tuple[str, int] | None = None
        self._release: list[Action] = []
        self._hello_due = False
        self._ids = itertools.count()
        self._seq = 0
        self._out: list[RobotMessage] = []

    @property
    def pose(self) -> Pose | None:
        """Where the vehicle is (its last ``state``), as a cell and heading."""
        state = self.master.state
        if state is None or state.agv_position is None:
            return None
        if not state.agv_position.position_initialized:
            return None
        pos = state.agv_position
        cell = self.master.nodes.cell_of(pos.x, pos.y)
        if min(cell) < 0:
            return None
        return Pose(cell=cell, heading=heading_of(pos.theta) if self.turning else None)

    def activity(self) -> Activity | None:
        """The first unfinished action the vehicle holds and what it does with it."""
        for aid in self.held:
            phase = self.phase.get(aid, "received")
            return Activity(action_id=aid, state=phase)  # type: ignore[arg-type]
        return None

    # ------------------------------------------------------------------ gateway link
    def connected(self, now_s: float) -> None:
        """A gateway link is up: say hello once a fresh ``state`` of the vehicle arrives
        (asked for with ``stateRequest``; the vehicle may have moved while it was away; a
        2.1.0 vehicle whose factsheet has not come is asked for it too): after
        a restart the vehicle's order is taken over first (:meth:`VehicleMaster.adopt`), and
        the actions it finished meanwhile are reported."""
        self.link_up, self._seq = True, 0
        self.master.state = None  # the vehicle was away: where it is now, it says anew
        self._hello_due = True
        self.master.request_state(now_s)
        if self.master.factsheet is None and self.master.version != "2.0.0":
            self.master.request_factsheet(now_s)  # 2.0.0 has no factsheetRequest

    def state_seen(self) -> None:
        """The master got a ``state`` message (the hello may be due)."""
        if self._hello_due and self.link_up and self.master.state is not None:
            self._hello()

    def _hello(self) -> None:
        self._hello_due = False
        state = self.master.state
        if state is not None and not self.held:
            finished, _ = self.master.adopt(state)
            for aid in finished:
                self._finished[aid] = None
        self._send(Hello, robot_id=self.robot_id, pose=self.pose,
                   acked=list(self.held)[-HISTORY:], finished=list(self._finished)[-HISTORY:],
                   current=self.activity())

    def disconnected(self) -> None:
        """The gateway link is gone (what the vehicle does goes on)."""
        self.link_up = False

    def receive(self, msg: AnyMessage, now_s: float) -> None:
        """One message from the gateway."""
        if isinstance(msg, Welcome):
            self.paused = msg.paused
            if msg.paused:
                self.master.pause(now_s)
            self._actions(list(msg.resend))
        elif isinstance(msg, Action):
            self._actions([msg])
        elif isinstance(msg, CancelAction):
            if msg.action_id in self.held:
                self.master.cancel([msg.action_id], now_s)
        elif isinstance(msg, Pause):
            self.paused = True
            self.master.pause(now_s)
        elif isinstance(msg, Resume):
            self.paused = False
            self.master.resume(now_s)

    def _actions(self, actions: list[Action]) -> None:
        fresh = self.master.adopt_actions(actions)
        for action in actions:
            if action not in fresh and action.action_id not in self.held:
                self.held[action.action_id] = action  # in the base of a taken-over order
                self._send(Ack, action_id=action.action_id)
                continue
            aid = action.action_id
            if aid in self.held or aid in self._finished:
                self._send(Ack, action_id=aid)
                if aid in self._finished:
                    self._send(Finished, action_id=aid, pose=self.pose)
                continue
            refusal = self._refusal(action, self._release)
            if refusal is not None:
                code, detail = refusal
                self._refused = (plan_key(aid), parse_action_id(aid)[2])
                self._send(ActionRefused, action_id=aid, pose=self.pose, code=code,
                           detail=detail)
                continue
            if self.plan_of is not None and plan_key(aid) != self._plan_key:
                self._plan_key = plan_key(aid)
                self.master.set_plan(self.plan_of(action))
            self.held[aid] = action
            self._release.append(action)
            self._send(Ack, action_id=aid)

    def commit(self, now_s: float) -> None:
        """Release the actions acknowledged since the last call to the vehicle, as one order
        or order update (a driver calls it once it has read what the gateway sent at once)."""
        release, self._release = self._release, []
        self.master.release(release, now_s)

    def _refusal(self, action: Action, pending: list[Action]) -> tuple[str, str] | None:
        key, index = plan_key(action.action_id), parse_action_id(action.action_id)[2]
        if self._refused is not None:
            if key == self._refused[0] and index > self._refused[1]:
                return "queued_behind", "an earlier action of this plan was refused"
            self._refused = None
        last = pending[-1] if pending else next(reversed(self.held.values()), None)
        due = last.dst if last is not None else self.pose
        src = action.src
        if due is not None and (tuple(src.cell) != tuple(due.cell) or (
                None not in (src.heading, due.heading) and src.heading != due.heading)):
            return "pose_mismatch", (f"it starts at {list(src.cell)} {src.heading or ''}, the "
                                     f"vehicle will stand at {list(due.cell)} "
                                     f"{due.heading or ''}")
        return None

    # ------------------------------------------------------------------ vehicle side
    def vehicle(self, effect: Effect) -> None:
        """A report of the master (link changes are the driver's business)."""
        if not isinstance(effect, Report):
            return
        aid = effect.action_id
        if effect.kind == "refused":
            self.held.pop(aid, None)
            self._refused = (plan_key(aid), parse_action_id(aid)[2])
            self._send(ActionRefused, action_id=aid, pose=self.pose, code="cannot_execute",
                       detail=effect.detail[:500])
            return
        if effect.kind in ("finished", "cancelled"):
            self.held.pop(aid, None)
            self.phase.pop(aid, None)
            if effect.kind == "finished":
                self._finished[aid] = None
                if len(self._finished) > HISTORY:
                    del self._finished[next(iter(self._finished))]
        elif effect.kind in ("started", "unblocked"):
            self.phase[aid] = "running" if effect.kind == "started" else "received"
        else:
            self.phase[aid] = "blocked"
        self._send(REPORTS[effect.kind], action_id=aid, pose=self.pose)

    def state(self, battery: float | None = None) -> None:
        """Send a ``state`` snapshot to the gateway."""
        current = self.activity()
        activity: RobotActivity = current.state if current is not None else (
            "paused" if self.paused else "idle")
        self._send(State, robot_id=self.robot_id, pose=self.pose, activity=activity,
                   current=current, battery=battery)

    # ------------------------------------------------------------------ effects
    def _send(self, kind: type[RobotMessage], **fields: Any) -> None:
        if not self.link_up or (self._hello_due and kind is not Hello):
            return
        self._out.append(kind(v=2, msg_id=f"vda{self.robot_id}-{next(self._ids)}",
                              seq=self._seq, **fields))
        self._seq += 1

    def drain(self) -> list[RobotMessage]:
        """The messages for the gateway, in order (then cleared)."""
        out, self._out = self._out, []
        return out

