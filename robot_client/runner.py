"""The action runner: a sans-I/O controller that drives one grid action at a time.

It is fed the current time, the pose estimate and the bumper state on every control tick and
answers with the base control command (speed mm/s, radius mm) for the Kobuki; what happened
(started, blocked, unblocked, finished) is collected and handed out by :meth:`drain`. It never
reads a clock or touches a device.

Actions are the plan's: ``wait`` (stay ``duration_ms``), ``turn`` (same cell, new heading: spin
in place the shorter way, by the pose estimate -- odometry corrected by AprilTag fixes -- to
within ``heading_tol_rad``) and ``move`` (to a 4-neighbour cell: drive along the line between
the two cell centres, steering back onto it, until the target centre is reached within
``position_tol_m``). Under the ``turning`` motion model (the action has headings) a move keeps
its heading and goes one cell forward: the robot drives straight and refuses (ValueError) a move
whose start heading it does not hold (its estimated heading is nearest another compass
heading); an ``omni`` move (no headings) first spins to face the target and, if a target
heading is given that differs from the direction of travel, spins to it at the end. A bumper
contact during a turn or move stops the base and pauses the action until ``bumper_pause_ms``
(5 s, as on the demonstrator) after the last contact; it then continues where it is.
:meth:`ActionRunner.abort` drops the current action: a move under way (a bumper stop that a
replan cancels) first drives back to its source cell and heading, then reports ``cancelled``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Literal

from protocol.messages import Heading
from robot_client.floor import HEADING_ANGLE, Cell, FloorGrid, heading_of_step, nearest_heading
from robot_client.kobuki import twist_to_base_control
from robot_client.odometry import Pose, wrap_angle

ActionKind = Literal["wait", "turn", "move"]
EventKind = Literal["started", "blocked", "unblocked", "finished", "cancelled"]
STOP: tuple[int, int] = (0, 0)


@dataclass(frozen=True, slots=True)
class GridAction:
    """One action of a robot's plan: from ``src`` (cell, heading) to ``dst``.

    Headings are None in the omni motion model.
    """

    action_id: str
    src: Cell
    dst: Cell
    src_heading: Heading | None = None
    dst_heading: Heading | None = None
    duration_ms: float = 1000.0

    @property
    def kind(self) -> ActionKind:
        """``move`` if the cell changes, ``turn`` if only the heading does, else ``wait``."""
        if self.src != self.dst:
            return "move"
        if self.dst_heading is not None and self.src_heading not in (None, self.dst_heading):
            return "turn"
        return "wait"

    def validate(self) -> None:
        """ValueError unless a move goes to a 4-neighbour (under ``turning``: forward along its
        unchanged heading) and the duration is positive."""
        if self.kind == "move":
            travel = heading_of_step(self.src, self.dst)
            if self.src_heading is not None and not (
                    self.src_heading == travel and self.dst_heading in (None, travel)):
                raise ValueError(
                    f"action {self.action_id}: a move from {list(self.src)} to "
                    f"{list(self.dst)} goes {travel}, but it starts facing {self.src_heading} "
                    f"and ends facing {self.dst_heading} (a move keeps its heading)")
        if self.duration_ms <= 0:
            raise ValueError(f"action {self.action_id}: duration {self.duration_ms} ms <= 0")


@dataclass(frozen=True, slots=True)
class RunnerEvent:
    """Something the gateway must hear about: ``kind`` of action ``action_id`` at ``t_ms``."""

    kind: EventKind
    action_id: str
    t_ms: float
    pose: Pose


@dataclass(frozen=True, slots=True)
class RunnerParams:
    """Controller gains, limits and tolerances."""

    max_speed_m_s: float = 0.20
    min_speed_m_s: float = 0.03
    max_turn_rad_s: float = 1.2
    min_turn_rad_s: float = 0.15
    linear_gain: float = 1.5
    """Forward speed per metre left to go (1/s)."""
    turn_gain: float = 2.5
    """Turn rate per radian of heading error (1/s)."""
    lookahead_m: float = 0.15
    """Steer towards the point this far ahead on the line of travel."""
    position_tol_m: float = 0.005
    heading_tol_rad: float = math.radians(1.5)
    align_tol_rad: float = math.radians(12.0)
    """Spin in place before driving when facing further than this from the target."""
    bumper_pause_ms: float = 5000.0
    wheelbase_m: float = 0.230


Phase = Literal["idle", "align", "drive", "final_turn", "wait"]
_FIRST_PHASE: dict[ActionKind, Phase] = {"wait": "wait", "turn": "final_turn", "move": "align"}


@dataclass
class ActionRunner:
    """Executes one :class:`GridAction` at a time on the floor grid (see module doc)."""

    floor: FloorGrid
    params: RunnerParams = field(default_factory=RunnerParams)
    action: GridAction | None = None
    phase: Phase = "idle"
    _t_start: float = 0.0
    _pause_until: float | None = None
    _started: bool = False
    _returning: bool = False
    _events: list[RunnerEvent] = field(default_factory=list)

    @property
    def busy(self) -> bool:
        """Whether an action is being executed."""
        return self.action is not None

    @property
    def paused(self) -> bool:
        """Whether the current action is paused by a bumper contact."""
        return self._pause_until is not None

    def start(self, action: GridAction, now_ms: float, pose: Pose | None = None) -> None:
        """Begin ``action`` (reported as ``started`` on the next :meth:`step`); ``pose`` is
        the current estimate, against which a turning move's start heading is checked."""
        if self.action is not None:
            raise RuntimeError(f"runner busy with {self.action.action_id}; "
                               f"cannot start {action.action_id}")
        action.validate()
        if action.kind == "move" and action.src_heading is not None and pose is not None:
            facing = nearest_heading(pose.theta)
            if facing != action.src_heading:
                raise ValueError(
                    f"action {action.action_id}: a move from {list(action.src)} facing "
                    f"{action.src_heading}, but the robot faces {facing} (heading "
                    f"{math.degrees(pose.theta):.0f} deg): turn first")
        self.action, self._t_start, self._started = action, now_ms, False
        self._pause_until, self._returning = None, False
        self.phase = _FIRST_PHASE[action.kind]

    def abort(self, now_ms: float, pose: Pose) -> None:
        """Drop the current action (a ``cancel``). A move that started drives back to its
        source cell (turning round if need be) and, if it had a start heading, turns back to
        it; ``cancelled`` is reported once there. Anything else stops at once, reported as
        ``cancelled`` on the spot."""
        a = self.action
        if a is None or self._returning:
            return
        self._pause_until = None
        if a.kind != "move" or not self._started:
            self._emit("cancelled", now_ms, pose)
            self.action, self.phase = None, "idle"
            return
        self.action = GridAction(a.action_id, a.dst, a.src, None, a.src_heading, a.duration_ms)
        self.phase, self._returning = "align", True

    def drain(self) -> list[RunnerEvent]:
        """The events since the last call, oldest first."""
        out, self._events = self._events, []
        return out

    def step(self, now_ms: float, pose: Pose, bumper: bool) -> tuple[int, int]:
        """One control tick: the base command (speed mm/s, radius mm) to send now."""
        a = self.action
        if a is None:
            return STOP
        if not self._started:
            self._started = True
            self._emit("started", now_ms, pose)
        if self.phase != "wait" and self._bumper_holds(now_ms, pose, bumper):
            return STOP
        v, w = self._control(a, now_ms, pose)
        if self.action is None:
            return STOP
        return twist_to_base_control(v, w, self.params.wheelbase_m)

    def _emit(self, kind: EventKind, now_ms: float, pose: Pose) -> None:
        assert self.action is not None
        if self._returning and kind in ("blocked", "unblocked"):
            return  # a bumper holds the way back too, but the action is no longer reported
        self._events.append(RunnerEvent(kind, self.action.action_id, now_ms, pose))

    def _bumper_holds(self, now_ms: float, pose: Pose, bumper: bool) -> bool:
        """Update the bumper pause; True while the action must stay paused."""
        if bumper:
            if self._pause_until is None:
                self._emit("blocked", now_ms, pose)
            self._pause_until = now_ms + self.params.bumper_pause_ms
            return True
        if self._pause_until is None:
            return False
        if now_ms < self._pause_until:
            return True
        self._pause_until = None
        self._emit("unblocked", now_ms, pose)
        return False

    def _finish(self, now_ms: float, pose: Pose) -> tuple[float, float]:
        self._emit("cancelled" if self._returning else "finished", now_ms, pose)
        self.action, self.phase, self._returning = None, "idle", False
        return 0.0, 0.0

    def _control(self, a: GridAction, now_ms: float, pose: Pose) -> tuple[float, float]:
        """(v m/s, w rad/s) for the current phase, advancing phases as targets are reached."""
        p = self.params
        if self.phase == "wait":
            if now_ms - self._t_start >= a.duration_ms:
                return self._finish(now_ms, pose)
            return 0.0, 0.0
        if self.phase == "final_turn":
            target = HEADING_ANGLE[a.dst_heading] if a.dst_heading else pose.theta
            err = wrap_angle(target - pose.theta)
            if abs(err) <= p.heading_tol_rad:
                return self._finish(now_ms, pose)
            return 0.0, self._turn_rate(err)
        travel = HEADING_ANGLE[heading_of_step(a.src, a.dst)]
        if self.phase == "align":
            err = wrap_angle(travel - pose.theta)
            if abs(err) > p.align_tol_rad:
                return 0.0, self._turn_rate(err)
            self.phase = "drive"
        tx, ty = self.floor.centre(a.dst)
        ux, uy = math.cos(travel), math.sin(travel)
        ahead = (tx - pose.x) * ux + (ty - pose.y) * uy  # distance left along the line
        if ahead <= p.position_tol_m:
            if a.dst_heading is None or a.dst_heading == heading_of_step(a.src, a.dst):
                return self._finish(now_ms, pose)
            self.phase = "final_turn"
            return 0.0, 0.0
        lateral = (ty - pose.y) * ux - (tx - pose.x) * uy  # > 0: the line is to our left
        steer = wrap_angle(travel + math.atan2(lateral, p.lookahead_m) - pose.theta)
        if abs(steer) > 2 * p.align_tol_rad:
            self.phase = "align"
            return 0.0, self._turn_rate(steer)
        v = min(p.max_speed_m_s, max(p.min_speed_m_s, p.linear_gain * ahead))
        w = max(-p.max_turn_rad_s, min(p.max_turn_rad_s, p.turn_gain * steer))
        return v, w

    def _turn_rate(self, err: float) -> float:
        """Spin rate for a heading error: proportional, clamped to [min, max] turn rate."""
        p = self.params
        rate = min(p.max_turn_rad_s, max(p.min_turn_rad_s, p.turn_gain * abs(err)))
        return math.copysign(rate, err)
