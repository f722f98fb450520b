"""What the executor hands its driver through ``Executor.drain()``.

A driver (asyncio server, in-memory server, discrete-event loop) turns these into I/O: a
``Dispatch`` becomes a message to a robot, a ``SolveRequest`` a call to the planner, and so on.
Times are milliseconds since the start of execution.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from gateway.execution.actions import ActionKind
from gateway.planning.grid import Cell
from gateway.planning.plan import Plan


@dataclass(slots=True)  # not frozen (a frozen one costs 4x to build): one per action
class Dispatch:
    """Robot ``robot`` may now execute action ``action`` (index i of a_i^k) of plan ``plan``.

    With lookahead dispatch it may be queued behind the robot's previous action: the robot
    starts it only after finishing that one (actions run strictly in index order).
    Under the ``turning`` motion model ``src_heading``/``dst_heading`` are the poses' headings
    (0 east, 1 south, 2 west, 3 north); under ``omni`` they are None.
    """

    plan: int
    robot: int
    action: int
    src: Cell
    dst: Cell
    duration_ms: float
    src_heading: int | None = None
    dst_heading: int | None = None

    @property
    def kind(self) -> ActionKind:
        """"move" (the cell changes), "turn" (only the heading does) or "wait"."""
        if self.src != self.dst:
            return "move"
        return "wait" if self.src_heading == self.dst_heading else "turn"


@dataclass(frozen=True, slots=True)
class Cancel:
    """A replan cancels this blocked, not yet moving action; the robot stays on ``src``.

    The driver answers with ``Executor.cancelled`` (or, if the robot had already started to
    move, with ``started``/``finished`` as usual).
    """

    plan: int
    robot: int
    action: int


@dataclass(frozen=True, slots=True)
class Trigger:
    """A replan was decided by ``policy`` ("slack", "random" or "operator")."""

    policy: str
    fleet_slack_ms: float


@dataclass(frozen=True, slots=True)
class SolveRequest:
    """All robots are idle after a trigger: plan from ``starts`` to ``goals``.

    ``headings`` are the robots' current headings under the ``turning`` motion model (the new
    plan must start with them; goal headings are free), None under ``omni``.

    The driver solves (charging the solver's time as it is configured to) and then calls
    ``Executor.adopt_plan`` or, if no plan was found, ``Executor.abandon_replan``.
    """

    starts: tuple[Cell, ...]
    goals: tuple[Cell, ...]
    headings: tuple[int, ...] | None = None
    obstacles: tuple[tuple[Cell, float], ...] = ()
    """Informed replanning only: cells the fleet reported blocked, each with the time (ms)
    until which it is expected to stay blocked; the planner keeps every robot off them until
    then."""
    shadow: bool = False
    """Shadow planning: the fleet keeps moving; answer with ``Executor.shadow_solved`` (the
    plan, or None if there is none), not ``adopt_plan``."""
    start_ms: float | None = None
    """When the plan is expected to start (None: as soon as it is solved); the obstacles'
    times count from then."""

    def forbidden(self, now_ms: float, action_ms: float) -> list[tuple[Cell, int, int]]:
        """The obstacles as the planner's forbidden ``(cell, first, last timestep)``: from
        the plan's first timestep until the first one that starts at or after the block's
        expected end, a timestep being ``action_ms`` from ``start_ms`` (else ``now_ms``)."""
        t0 = now_ms if self.start_ms is None else self.start_ms
        return [(cell, 0, math.ceil((until - t0) / action_ms))
                for cell, until in self.obstacles if until > t0]


@dataclass(frozen=True, slots=True)
class PlanAdopted:
    """Plan number ``plan`` (0 for the first) is now being executed."""

    plan: int
    paths: Plan


@dataclass(frozen=True, slots=True)
class Rescheduled:
    """The current plan's Type 2 edges were switched (reschedule-first, no stop): on each
    ``(cell, first, second)`` of ``switches`` robot ``first`` now passes before ``second``;
    the estimate says the fleet finishes ``gain_ms`` earlier (sum of completion times)."""

    switches: tuple[tuple[Cell, int, int], ...]
    gain_ms: float


@dataclass(frozen=True, slots=True)
class Completed:
    """Every robot has finished its last action."""

    soc_ms: float
    makespan_ms: float


Command = Dispatch | Cancel | Trigger | SolveRequest | PlanAdopted | Rescheduled | Completed
