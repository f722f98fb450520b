"""The executor contract (:mod:`gateway.execution.core`) holds for both execution cores: the
one-shot :class:`Executor` and the :class:`LifelongExecutor` pass the same suite
(:func:`tests.execution.core_contract.check_core`)."""

from __future__ import annotations

from collections.abc import Callable

import pytest

from gateway.execution.commands import Cancel, Dispatch, SolveRequest
from gateway.execution.core import Core
from gateway.execution.lifelong.errands import TaskDistances
from gateway.execution.lifelong.executor import LifelongExecutor, PlanRequest, WindowPlanner
from gateway.execution.lifelong.tasks import TaskPool
from gateway.execution.oneshot.executor import Executor
from gateway.planning.plan import Plan
from tests.execution.core_contract import CHECKS, Make, Rig
from tests.lifelong.support import small_problem

# A drives (0,0) -> (3,0); B drives (5,5) -> (5,3): two actions each, far apart.
PLAN = Plan.of([[(0, 0), (1, 0), (2, 0), (3, 0)], [(5, 5), (5, 4), (5, 3)]])


def settled(core: Core[object], answer: Callable[[object], None]) -> list[Dispatch]:
    """Drain ``core`` until it is quiet, answering each command but dispatches with
    ``answer``; the dispatches, in order."""
    out: list[Dispatch] = []
    while commands := core.drain():
        for c in commands:
            if isinstance(c, Dispatch):
                out.append(c)
            else:
                answer(c)
    return out


class OneShotRig:
    """The one-shot executor on :data:`PLAN`; a replan is abandoned (the plan goes on)."""

    def __init__(self) -> None:
        self.executor = Executor(PLAN, lookahead=1, max_replans=5)
        self.core: Core[object] = self.executor
        self.fleet = 2
        self.executor.start(0.0)

    def settle(self, now_ms: float) -> list[Dispatch]:
        return settled(self.core, lambda c: self._answer(c, now_ms))

    def _answer(self, c: object, now_ms: float) -> None:
        if isinstance(c, Cancel):
            self.executor.cancelled(c.robot, c.plan, c.action, now_ms)
        elif isinstance(c, SolveRequest):
            self.executor.abandon_replan(now_ms)

    def replan(self, now_ms: float) -> list[Dispatch]:
        self.executor.request_replan(now_ms)
        return self.settle(now_ms)


class LifelongRig:
    """The lifelong executor on a small random warehouse; its windows come from PIBT."""

    def __init__(self) -> None:
        prob = small_problem(3, robots=4, size=8, p_delay=0.0)
        self.executor = LifelongExecutor(
            prob.grid, prob.starts, None, TaskPool(prob.tasks, 6),
            distances=TaskDistances(prob.grid), lookahead=1, period_ms=1000.0, window=4)
        self.core: Core[object] = self.executor
        self.fleet = 4
        self.planner = WindowPlanner(prob.grid, 4, False, 3)
        self.executor.start(0.0)

    def settle(self, now_ms: float) -> list[Dispatch]:
        return settled(self.core, lambda c: self._answer(c, now_ms))

    def _answer(self, c: object, now_ms: float) -> None:
        if isinstance(c, PlanRequest):
            self.executor.adopt(self.planner(c), now_ms)

    def replan(self, now_ms: float) -> list[Dispatch]:
        due = self.executor.next_wakeup_ms()
        at = now_ms if due is None else max(now_ms, due)
        self.executor.tick(at)
        return self.settle(at)


RIGS: dict[str, Make] = {"one-shot": OneShotRig, "lifelong": LifelongRig}


@pytest.mark.parametrize("check", CHECKS, ids=lambda c: c.__name__.removeprefix("check_"))
@pytest.mark.parametrize("rig", RIGS)
def test_core_contract(rig: str, check: object) -> None:
    make = RIGS[rig]
    assert callable(check)
    check(make)


def test_both_rigs_are_rigs() -> None:
    rigs: list[Rig] = [OneShotRig(), LifelongRig()]
    assert [r.fleet for r in rigs] == [2, 4]
