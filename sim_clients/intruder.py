"""The intruder (DESIGN section 2; paper section 4.3): an unplanned occupant of one cell.

It appears at ``appear_ms`` (T_a), picks a random robot that still has a move ahead, and
targets the first cell that robot is estimated to begin entering (``reading="start"``, the
default) or to arrive on (``"arrival"``) at or after ``appear_ms + lead_ms`` (else the cell of
its last move). It waits until that cell is free
(looking every 100 ms), holds it, and leaves at ``leave_ms`` (T_d), also through a replan. If
the cell never became free by then, it never entered. The gateway knows none of this.
"""

from __future__ import annotations

import random
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from enum import Enum

from gateway.execution.params import INTRUDER_READINGS, PAPER, IntruderReading
from gateway.planning.grid import Cell
from gateway.planning.plan import Path
from sim_clients.world import INTRUDER, World

StartEstimate = Callable[[int, int], float]
"""``(robot, action) -> estimated time in ms`` of the robot's visit of the action's target:
``Monitor.start_ms`` or ``Monitor.completion_ms`` (see :attr:`IntruderConfig.reading`)."""


@dataclass(frozen=True, slots=True)
class IntruderConfig:
    """When the intruder comes and goes; the defaults are the paper's."""

    appear_ms: float = PAPER.intruder_appear_ms
    leave_ms: float = PAPER.intruder_leave_ms
    lead_ms: float = PAPER.intruder_lead_ms
    recheck_ms: float = PAPER.recheck_ms
    stay_ms: float | None = None
    """How long the intruder stays after its robot is estimated to need the cell (then it
    leaves at that time plus ``stay_ms`` instead of ``leave_ms``; None: the paper's fixed
    ``leave_ms``)."""
    reading: IntruderReading = "start"
    """How the paper's "scheduled to visit the vertex in T_a + 2 s" is read: the robot's move
    into the cell is estimated to START then (the default: the 2 s are the intruder's time to
    take the cell before the robot needs it, the paper's stated purpose), or to ARRIVE then
    (the robot may set off one action earlier: the intruder blocks it sooner)."""

    def __post_init__(self) -> None:
        if self.reading not in INTRUDER_READINGS:
            raise ValueError(f"reading must be one of {', '.join(INTRUDER_READINGS)}, got "
                             f"{self.reading!r}")
        if not 0 <= self.appear_ms < self.leave_ms:
            raise ValueError(f"need 0 <= appear_ms < leave_ms, got {self.appear_ms} and "
                             f"{self.leave_ms}")
        if self.stay_ms is not None and not 0 < self.stay_ms < float("inf"):
            raise ValueError(f"stay_ms must be a positive number, got {self.stay_ms}")
        if self.lead_ms < 0 or self.recheck_ms <= 0:
            raise ValueError("lead_ms must be >= 0 and recheck_ms > 0")


@dataclass(frozen=True, slots=True)
class IntruderEvent:
    """The intruder entered (``state="on"``) or left (``"off"``) ``cell`` at ``t_ms``."""

    t_ms: float
    cell: Cell
    state: str


def pick_target(rng: random.Random, paths: Sequence[Path], next_action: Sequence[int],
                start_ms: StartEstimate, not_before_ms: float) -> tuple[int, Cell] | None:
    """The robot and cell the intruder goes for, or None if no robot has a move ahead
    (:func:`pick_target_at` without the time)."""
    got = pick_target_at(rng, paths, next_action, start_ms, not_before_ms)
    return None if got is None else got[:2]


def pick_target_at(rng: random.Random, paths: Sequence[Path], next_action: Sequence[int],
                   start_ms: StartEstimate,
                   not_before_ms: float) -> tuple[int, Cell, float] | None:
    """The robot and cell the intruder goes for and when the robot is estimated to need it
    (``start_ms`` of the move), or None if no robot has a move ahead.

    ``next_action[k]`` is the index of robot k's first action that has not started. A move
    is an action whose two cells differ. The robot is drawn uniformly from those with a move
    ahead (in id order); the cell is the target of its first move not started whose estimated
    start is at or after ``not_before_ms``, else the target of its last move.
    """
    candidates = [k for k, path in enumerate(paths)
                  if any(path[i] != path[i + 1] for i in range(next_action[k], len(path) - 1))]
    if not candidates:
        return None
    robot = rng.choice(candidates)
    path = paths[robot]
    moves = [i for i in range(next_action[robot], len(path) - 1) if path[i] != path[i + 1]]
    for i in moves:
        if (need := start_ms(robot, i)) >= not_before_ms:
            return robot, path[i + 1], need
    return robot, path[moves[-1] + 1], start_ms(robot, moves[-1])


class IntruderState(Enum):
    """Where the intruder is in its life."""

    ABSENT = "absent"
    WAITING = "waiting"
    PRESENT = "present"
    GONE = "gone"


class Intruder:
    """The intruder's state machine on a :class:`World` (sans-I/O, driven with times).

    The driver calls :meth:`appear` at ``config.appear_ms`` with the chosen target (see
    :func:`pick_target`), then :meth:`wake` at every :meth:`next_wakeup_ms`.
    """

    def __init__(self, world: World, config: IntruderConfig | None = None) -> None:
        self.world = world
        self.config = config or IntruderConfig()
        self.state = IntruderState.ABSENT
        self.robot: int | None = None
        """The robot it went for (None if it never picked one)."""
        self.cell: Cell | None = None
        self.entered_ms: float | None = None
        self.leave_ms = self.config.leave_ms
        """When it leaves (with a stay: set when it appears)."""
        self._wake: float | None = self.config.appear_ms

    def next_wakeup_ms(self) -> float | None:
        """When :meth:`appear` or :meth:`wake` is due next; None once gone."""
        return self._wake

    def appear(self, now_ms: float, target: tuple[int, Cell] | None,
               need_ms: float | None = None) -> list[IntruderEvent]:
        """Arrive at ``now_ms`` going for ``target`` (``(robot, cell)``; None: stay away);
        with a stay, leave ``stay_ms`` after ``need_ms`` (when the robot is estimated to need
        the cell; default now)."""
        if self.state is not IntruderState.ABSENT:
            raise ValueError(f"the intruder already appeared (it is {self.state.value})")
        if target is None:
            self.state = IntruderState.GONE
            self._wake = None
            return []
        self.robot, self.cell = target
        if self.config.stay_ms is not None:
            self.leave_ms = max(now_ms, now_ms if need_ms is None else need_ms) \
                + self.config.stay_ms
        self.state = IntruderState.WAITING
        return self._try_enter(now_ms)

    def wake(self, now_ms: float) -> list[IntruderEvent]:
        """Leave at ``leave_ms``, or look at the cell again while waiting for it."""
        if self._wake is None or now_ms < self._wake or self.state is IntruderState.ABSENT:
            return []
        cell = self.cell
        assert cell is not None
        if now_ms >= self.leave_ms:
            was_present = self.state is IntruderState.PRESENT
            self.state = IntruderState.GONE
            self._wake = None
            if not was_present:
                return []
            self.world.release(cell, INTRUDER)
            return [IntruderEvent(now_ms, cell, "off")]
        return self._try_enter(now_ms)

    def _try_enter(self, now_ms: float) -> list[IntruderEvent]:
        cell = self.cell
        assert cell is not None
        if self.world.is_free(cell):
            self.world.occupy(cell, INTRUDER, now_ms)
            self.state = IntruderState.PRESENT
            self.entered_ms = now_ms
            self._wake = self.leave_ms
            return [IntruderEvent(now_ms, cell, "on")]
        self._wake = min(now_ms + self.config.recheck_ms, self.leave_ms)
        return []
