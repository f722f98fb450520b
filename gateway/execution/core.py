"""The executor contract: what a driver (the gateway's engine, the discrete-event simulator)
asks of an execution core, whichever mode it runs, and the checks every core makes alike.

Both :class:`~gateway.execution.oneshot.executor.Executor` (a whole plan up front) and
:class:`~gateway.execution.lifelong.executor.LifelongExecutor` (a shift planned window by
window) are a :class:`Core`: they take the robots' reports and the driver's ticks, each with
the present time, and hand everything they decide out through :meth:`Core.drain`. The two
stay separate algorithms; they share this contract and :func:`check_time` /
:func:`check_robot`, not code paths.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Protocol, TypeVar

from gateway.execution.errors import ExecutionError
from gateway.execution.params import PAPER

C_co = TypeVar("C_co", covariant=True)

MONITOR_PERIOD_MS = PAPER.monitor_period_ms
"""Drivers call ``tick()`` at every multiple of this while running."""


class Core(Protocol[C_co]):
    """A sans-I/O executor: inputs carry the present (``now_ms``, never before the last
    input's), outputs are commands of type ``C_co`` taken with :meth:`drain`. A report about an
    action is ``(robot, plan, action, now_ms)``: ``plan`` is the plan (one-shot) or segment
    (lifelong) that dispatched it, ``action`` its number in the robot's sequence. A report
    the core cannot take raises :class:`~gateway.execution.errors.ExecutionError` and changes
    nothing."""

    @property
    def now_ms(self) -> float:
        """Time of the latest accepted input."""
        ...

    @property
    def done(self) -> bool:
        """True once the run is over (every robot idle at its end)."""
        ...

    @property
    def paused(self) -> bool:
        """True while nothing new is dispatched (:meth:`pause` .. :meth:`resume`)."""
        ...

    def start(self, now_ms: float) -> None:
        """Begin the run at ``now_ms`` (once)."""

    def started(self, robot: int, plan: int, action: int, now_ms: float) -> None:
        """The robot began the action (it must be at the head of the robot's queue)."""

    def finished(self, robot: int, plan: int, action: int, now_ms: float) -> None:
        """The robot completed the action (it must have started)."""

    def blocked(self, robot: int, plan: int, action: int, now_ms: float) -> None:
        """The robot found the action's target cell taken, before starting it."""

    def stopped(self, robot: int, plan: int, action: int, now_ms: float) -> None:
        """A move under way was stopped by an obstacle."""

    def unblocked(self, robot: int, plan: int, action: int, now_ms: float) -> None:
        """The action's target cell became free again."""

    def cancelled(self, robot: int, plan: int, action: int, now_ms: float) -> None:
        """The robot confirms a cancel the core asked for."""

    def refused(self, robot: int, plan: int, action: int, now_ms: float,
                reason: str = "") -> None:
        """The robot will not execute the (not started) action: it and the robot's later
        dispatched actions go back to not dispatched, to be dispatched again later."""

    def tick(self, now_ms: float) -> None:
        """The present moved on (the driver's periodic tick, or a wake-up it asked for)."""

    def pause(self, now_ms: float) -> None:
        """Dispatch nothing new until :meth:`resume`."""

    def resume(self, now_ms: float) -> None:
        """Dispatch again."""

    def next_wakeup_ms(self) -> float | None:
        """When the core wants its next :meth:`tick` before the periodic one (None: no need)."""

    def drain(self) -> Sequence[C_co]:
        """The commands emitted since the last call, in order."""
        ...


def check_time(now_ms: float, last_ms: float, started: bool, run: str) -> None:
    """Refuse an input at ``now_ms`` before ``start()`` (``run`` names what has not started),
    before the last input's ``last_ms``, NaN or infinite."""
    if not started:
        raise ExecutionError(f"{run} has not started: call start() first")
    if not now_ms >= last_ms:  # also rejects NaN
        raise ExecutionError(f"time went backwards: {now_ms} ms < last input at {last_ms} ms")
    if math.isinf(now_ms):
        raise ExecutionError(f"time must be finite, got {now_ms}")


def check_start(now_ms: float, started: bool) -> None:
    """Refuse a second ``start()`` and a start time that is not finite and >= 0."""
    if started:
        raise ExecutionError("start() was already called")
    if not (math.isfinite(now_ms) and now_ms >= 0):
        raise ExecutionError(f"start time must be a finite number >= 0, got {now_ms}")


def check_robot(robot: int, fleet: int) -> None:
    """Refuse a robot number outside the fleet of ``fleet`` robots."""
    if not 0 <= robot < fleet:
        raise ExecutionError(f"unknown robot {robot} (the fleet has {fleet})")
