"""A simulated robot as a sans-I/O state machine (the paper's simulator, section 4.2).

The driver hands it a :class:`~gateway.execution.commands.Dispatch` or a ``Cancel`` with the
current time, calls :meth:`SimRobot.wake` at :meth:`SimRobot.next_wakeup_ms`, and forwards the
:class:`RobotEvent` values it gets back to the executor (or over a websocket). A move first
checks the :class:`~sim_clients.world.World`: if the target is free the robot starts at once and
holds both cells until it arrives ``duration`` later; if not, it reports ``blocked`` and looks
again every 100 ms, then reports ``unblocked`` and ``started`` together. A wait or a turn
(target cell equal to source) needs no check and holds only its cell; a turn changes the
robot's heading (turning motion model), and a dispatch that starts from another heading than
the one the robot will hold is refused. While blocked, a matching ``Cancel`` returns it to
idle.

Lookahead dispatch: a busy robot queues further dispatches (each must start where the previous
one ends) and runs them strictly in order, the next one at the instant the current one finishes.
A ``Cancel`` of a queued action drops it and every action queued behind it.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass
from enum import Enum

from gateway.execution.commands import Dispatch
from gateway.execution.params import PAPER
from gateway.planning.grid import Cell
from sim_clients.world import World

RECHECK_MS = PAPER.recheck_ms
"""How often a blocked robot looks at its target cell again."""


class RobotState(Enum):
    """What a simulated robot is doing."""

    IDLE = "idle"
    BLOCKED = "blocked"
    MOVING = "moving"


@dataclass(frozen=True, slots=True)
class RobotEvent:
    """A report of robot ``robot`` about action ``action`` of plan ``plan`` at ``t_ms``.

    ``kind`` is one of "started", "finished", "blocked", "unblocked", "cancelled": the names
    of the matching ``Executor`` methods.
    """

    kind: str
    robot: int
    plan: int
    action: int
    t_ms: float


class SimRobotError(ValueError):
    """A command the robot cannot follow (wrong robot, wrong source cell, busy)."""


class SimRobot:
    """One simulated robot on a :class:`World`."""

    def __init__(self, robot: int, world: World, cell: Cell, *,
                 recheck_ms: float = RECHECK_MS, heading: int | None = None) -> None:
        if recheck_ms <= 0:
            raise ValueError(f"recheck_ms must be positive, got {recheck_ms}")
        self.robot = robot
        self.world = world
        self.cell = cell
        """Where the robot stands; while moving, the cell it is leaving."""
        self.heading = heading
        """Its heading (turning motion model; None for omni); while turning, the old one."""
        self.state = RobotState.IDLE
        self.recheck_ms = recheck_ms
        self._current: Dispatch | None = None
        self._duration = 0.0
        self._queue: deque[tuple[Dispatch, float]] = deque()  # (action, extra_ms) not begun
        self._wake: float | None = None
        self._last: tuple[int, int] | None = None

    @property
    def current(self) -> Dispatch | None:
        """The action being executed or waited for, None when idle."""
        return self._current

    @property
    def queued(self) -> tuple[Dispatch, ...]:
        """Actions dispatched behind the current one, in the order they will run."""
        return tuple(d for d, _ in self._queue)

    def next_wakeup_ms(self) -> float | None:
        """When :meth:`wake` has something to do: arrival, or the next look at a taken cell."""
        return self._wake

    def dispatch(self, d: Dispatch, now_ms: float, extra_ms: float = 0.0) -> list[RobotEvent]:
        """Begin ``d`` at ``now_ms`` (or queue it behind the actions the robot holds); it lasts
        ``d.duration_ms + extra_ms`` once it starts.

        A repeat of a held or the last action is ignored (the protocol resends after a
        reconnect). Raises :class:`SimRobotError` for another robot's action, a source cell that
        is not where the robot stands (or where its last held action ends), an action index not
        after the last held one, or a negative duration.
        """
        key = (d.plan, d.action)
        held = [x for x, _ in self._queue]
        if self._current is not None:
            held.insert(0, self._current)
        if any(key == (x.plan, x.action) for x in held):
            return []
        if key == self._last and self._current is None:
            return []
        if d.robot != self.robot:
            raise SimRobotError(f"robot {self.robot} got a dispatch for robot {d.robot}")
        end = held[-1].dst if held else self.cell
        if d.src != end:
            where = f"its last held action ends on {end}" if held else f"robot is on {end}"
            raise SimRobotError(f"robot {self.robot}: {where}, dispatch starts at {d.src}")
        facing = held[-1].dst_heading if held else self.heading
        if d.src_heading != facing:
            raise SimRobotError(f"robot {self.robot} will face {facing}, but {d.kind} "
                                f"{d.plan}.{d.robot}.{d.action} starts facing {d.src_heading}")
        if held and (d.plan, d.action) <= (held[-1].plan, held[-1].action):
            raise SimRobotError(f"robot {self.robot} holds {held[-1]}; {d} does not come after")
        duration = d.duration_ms + extra_ms
        if duration < 0:
            raise SimRobotError(f"action duration {duration} ms is negative")
        if held:
            self._queue.append((d, extra_ms))
            return []
        return self._begin(d, duration, now_ms)

    def _begin(self, d: Dispatch, duration: float, now_ms: float) -> list[RobotEvent]:
        """Make ``d`` the current action at ``now_ms``: start it or wait for its cell."""
        self._current = d
        self._duration = duration
        if d.dst == d.src or self.world.is_free(d.dst):
            return [self._start(now_ms)]
        self.state = RobotState.BLOCKED
        self._wake = now_ms + self.recheck_ms
        return [RobotEvent("blocked", self.robot, d.plan, d.action, now_ms)]

    def cancel(self, plan: int, action: int, now_ms: float) -> list[RobotEvent]:
        """Drop action ``action`` of ``plan`` if the robot is still waiting for its cell, or has
        it queued; every action queued behind it is dropped too (one ``cancelled`` each).

        A moving robot finishes its action as usual; a cancel for anything else is stale and
        ignored.
        """
        keys = [(x.plan, x.action) for x, _ in self._queue]
        if (plan, action) in keys:
            pos = keys.index((plan, action))
            dropped = keys[pos:]
            for _ in dropped:
                self._queue.pop()
            return [RobotEvent("cancelled", self.robot, p, a, now_ms) for p, a in dropped]
        d = self._current
        if self.state is not RobotState.BLOCKED or d is None or (d.plan, d.action) != (
                plan, action):
            return []
        self.state = RobotState.IDLE
        self._current = None
        self._wake = None
        self._last = None  # a cancelled action may be dispatched again (replan abandoned)
        events = [RobotEvent("cancelled", self.robot, plan, action, now_ms)]
        while self._queue:
            q, _ = self._queue.popleft()
            events.append(RobotEvent("cancelled", self.robot, q.plan, q.action, now_ms))
        return events

    def wake(self, now_ms: float) -> list[RobotEvent]:
        """Arrive, or look at the taken cell again; nothing if called before it is due."""
        if self._wake is None or now_ms < self._wake:
            return []
        d = self._current
        assert d is not None
        if self.state is RobotState.MOVING:
            if d.dst != d.src:
                self.world.release(d.src, self.robot)
            self.cell = d.dst
            self.heading = d.dst_heading
            self.state = RobotState.IDLE
            self._current = None
            self._wake = None
            self._last = (d.plan, d.action)
            events = [RobotEvent("finished", self.robot, d.plan, d.action, now_ms)]
            if self._queue:
                nxt, extra = self._queue.popleft()
                events += self._begin(nxt, nxt.duration_ms + extra, now_ms)
            return events
        if not self.world.is_free(d.dst):
            self._wake = now_ms + self.recheck_ms
            return []
        return [RobotEvent("unblocked", self.robot, d.plan, d.action, now_ms),
                self._start(now_ms)]

    def _start(self, now_ms: float) -> RobotEvent:
        d = self._current
        assert d is not None
        if d.dst != d.src:
            self.world.occupy(d.dst, self.robot, now_ms)
        self.state = RobotState.MOVING
        self._wake = now_ms + self._duration
        return RobotEvent("started", self.robot, d.plan, d.action, now_ms)
