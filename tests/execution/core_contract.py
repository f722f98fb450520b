"""The executor contract (:class:`gateway.execution.core.Core`) as a suite any execution core
must pass: ``check_core(make)`` runs every check on fresh rigs from ``make``.

A :class:`Rig` is a started core and the driver's side of it: :meth:`Rig.settle` answers what
the core asked for (a cancel is confirmed, a plan request answered: an abandoned replan for
the one-shot executor, a planned window for the lifelong one) and returns the dispatches;
:meth:`Rig.replan` makes the core plan again (a replan, or the next window).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Protocol

import pytest

from gateway.execution.commands import Dispatch
from gateway.execution.core import Core
from gateway.execution.errors import ExecutionError


class Rig(Protocol):
    """A started core and its driver (see the module's docstring)."""

    core: Core[object]
    fleet: int

    def settle(self, now_ms: float) -> list[Dispatch]:
        """Answer what the core asked for at ``now_ms``; the dispatches it emitted."""
        ...

    def replan(self, now_ms: float) -> list[Dispatch]:
        """Have the core plan again from ``now_ms`` on; the dispatches that follow."""
        ...


Make = Callable[[], Rig]


def _unchanged(rig: Rig, now_ms: float) -> None:
    """A refused input left no trace: same time, nothing emitted."""
    assert rig.core.now_ms == now_ms
    assert rig.settle(now_ms) == []


def _two_queued(dispatches: list[Dispatch]) -> tuple[Dispatch, Dispatch]:
    """A robot's head action and the one queued behind it."""
    for d in dispatches:
        behind = [e for e in dispatches if e.robot == d.robot and e.action == d.action + 1]
        if behind:
            return d, behind[0]
    raise AssertionError(f"no robot got two actions: {dispatches}")


def check_time_never_goes_backwards(make: Make) -> None:
    rig = make()
    d = rig.settle(0.0)[0]
    rig.core.tick(100.0)
    for bad in (50.0, math.nan):
        with pytest.raises(ExecutionError, match="time went backwards"):
            rig.core.started(d.robot, d.plan, d.action, bad)
        with pytest.raises(ExecutionError, match="time went backwards"):
            rig.core.tick(bad)
    with pytest.raises(ExecutionError, match="time must be finite"):
        rig.core.tick(math.inf)
    _unchanged(rig, 100.0)
    rig.core.started(d.robot, d.plan, d.action, 100.0)  # the present is still fine


def check_unknown_robot(make: Make) -> None:
    rig = make()
    d = rig.settle(0.0)[0]
    for robot in (rig.fleet, -1):
        with pytest.raises(ExecutionError, match=f"unknown robot {robot} "):
            rig.core.started(robot, d.plan, d.action, 10.0)
    _unchanged(rig, 0.0)


def check_report_not_at_the_head_of_the_queue(make: Make) -> None:
    rig = make()
    head, behind = _two_queued(rig.settle(0.0))
    for report in (rig.core.started, rig.core.finished):
        with pytest.raises(ExecutionError, match="queued behind"):
            report(behind.robot, behind.plan, behind.action, 10.0)
    _unchanged(rig, 0.0)
    rig.core.started(head.robot, head.plan, head.action, 10.0)
    rig.core.finished(head.robot, head.plan, head.action, 10.0 + head.duration_ms)
    rig.core.started(behind.robot, behind.plan, behind.action, 10.0 + head.duration_ms)


def check_duplicate_start(make: Make) -> None:
    rig = make()
    d = rig.settle(0.0)[0]
    rig.core.started(d.robot, d.plan, d.action, 10.0)
    with pytest.raises(ExecutionError, match="already started"):
        rig.core.started(d.robot, d.plan, d.action, 20.0)
    _unchanged(rig, 10.0)
    end = 10.0 + d.duration_ms
    rig.core.finished(d.robot, d.plan, d.action, end)
    with pytest.raises(ExecutionError, match="finished"):
        rig.core.finished(d.robot, d.plan, d.action, end)


def check_start_once_and_first(make: Make) -> None:
    rig = make()
    with pytest.raises(ExecutionError, match="already called"):
        rig.core.start(0.0)
    assert not rig.core.done and not rig.core.paused


def check_refusal_and_redispatch(make: Make) -> None:
    rig = make()
    head, behind = _two_queued(rig.settle(0.0))
    rig.core.refused(head.robot, head.plan, head.action, 10.0, "pose_mismatch: test")
    assert [d for d in rig.settle(10.0) if d.robot == head.robot] == []
    for d in (head, behind):  # both went back: neither is dispatched any more
        with pytest.raises(ExecutionError, match="not dispatched"):
            rig.core.started(d.robot, d.plan, d.action, 20.0)
    again = [d for d in rig.replan(20.0) if d.robot == head.robot]
    assert again, "the refusing robot got no work after the next plan"
    first = again[0]
    assert (first.src, first.src_heading) == (head.src, head.src_heading)
    rig.core.started(first.robot, first.plan, first.action, rig.core.now_ms)


def check_pause_lets_running_actions_finish(make: Make) -> None:
    rig = make()
    d = rig.settle(0.0)[0]
    rig.core.pause(5.0)
    assert rig.core.paused
    rig.core.started(d.robot, d.plan, d.action, 10.0)  # what runs goes on
    rig.core.finished(d.robot, d.plan, d.action, 10.0 + d.duration_ms)
    rig.core.resume(20.0 + d.duration_ms)
    assert not rig.core.paused and rig.core.now_ms == 20.0 + d.duration_ms


CHECKS = (check_time_never_goes_backwards, check_unknown_robot,
          check_report_not_at_the_head_of_the_queue, check_duplicate_start,
          check_start_once_and_first, check_refusal_and_redispatch,
          check_pause_lets_running_actions_finish)


def check_core(make: Make) -> None:
    """Run every check of the contract on fresh rigs from ``make``."""
    for check in CHECKS:
        check(make)
