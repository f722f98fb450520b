"""Each stateful class of a shift takes and restores its own snapshot: the live ADG, the task
pool and the lifelong executor. For each, a shift is driven for a while; its part is
snapshotted (through JSON where the snapshot is plain data), restored into a fresh object
that takes the live one's place in a copy of the shift, and both shifts are driven on with the
same inputs: they stay equal field by field (:func:`tests.lifelong.test_shift_replay.state`)."""

from __future__ import annotations

import copy
import json
from collections import OrderedDict
from typing import Any

import pytest

from gateway.execution.commands import Completed, Dispatch, Trigger
from gateway.execution.lifelong.errands import TaskDistances
from gateway.execution.lifelong.executor import LifelongExecutor, PlanRequest, WindowPlanner
from gateway.execution.lifelong.live_adg import LiveADG
from gateway.execution.lifelong.tasks import NewTask, TaskPool
from tests.lifelong.support import small_problem
from tests.lifelong.test_shift_replay import state

STEP_MS = 500.0
ROBOTS = 6


def _executor(seed: int, pool: TaskPool | None = None) -> LifelongExecutor:
    """A fresh shift's executor (not started) on a random map; its own pool unless given."""
    prob = small_problem(seed, robots=ROBOTS, size=10, p_delay=0.0)
    return LifelongExecutor(
        prob.grid, prob.starts, None, pool or TaskPool(prob.tasks, ROBOTS + 2),
        distances=TaskDistances(prob.grid), lookahead=1, period_ms=1000.0, window=3,
        threshold_ms=1500.0)


def _shift(seed: int) -> tuple[LifelongExecutor, WindowPlanner]:
    ex = _executor(seed)
    ex.start(0.0)
    return ex, WindowPlanner(ex.grid, ROBOTS, False, seed)


def _advance(ex: LifelongExecutor, planner: WindowPlanner, t: float, until: float) -> float:
    """Drive the shift from ``t`` to ``until``: plan requests answered at once, each robot
    starting its head action one step after it was dispatched and finishing it one step
    later, a submitted task every few steps, a tick every step."""
    step = 0
    while t < until:
        for c in ex.drain():
            if isinstance(c, PlanRequest):
                ex.adopt(planner(c), t)
            else:
                assert isinstance(c, Dispatch | Trigger | Completed)
        for r in range(ex.n):
            if ex.busy(r):
                head = ex.dispatched(r)[0]
                started, _ = ex.head_state(r)
                (ex.finished if started else ex.started)(r, head.plan, head.action, t)
        if step % 3 == 0:
            errands = ex.pool.task_list[step % len(ex.pool.task_list)]
            ex.pool.submit([NewTask(tuple(errands), 1, None)], t)
        step += 1
        t += STEP_MS
        ex.tick(t)
    return t


def _json(data: dict[str, Any]) -> dict[str, Any]:
    """``data`` after a round trip through JSON (as a journal stores it)."""
    out: dict[str, Any] = json.loads(json.dumps(data))
    return out


def _twins(seed: int) -> tuple[LifelongExecutor, WindowPlanner, LifelongExecutor,
                               WindowPlanner, float]:
    ex, planner = _shift(seed)
    t = _advance(ex, planner, 0.0, 9_000.0)
    ex.drain()  # what was emitted is output, not state: routed before a snapshot
    return ex, planner, copy.deepcopy(ex), copy.deepcopy(planner), t


def _same_after_more(live: LifelongExecutor, planner: WindowPlanner,
                     twin: LifelongExecutor, twin_planner: WindowPlanner, t: float) -> None:
    assert state(twin) == state(live)
    _advance(live, planner, t, t + 9_000.0)
    _advance(twin, twin_planner, t, t + 9_000.0)
    assert live.pool.finished > 0
    assert state(twin) == state(live)
    assert state(twin.pool) == state(live.pool)


@pytest.mark.parametrize("seed", [1, 2])
def test_live_adg_snapshot_round_trip(seed: int) -> None:
    live, planner, twin, twin_planner, t = _twins(seed)
    restored = LiveADG(twin.grid, _executor(seed).cell, None)
    restored.restore(**_json(live.adg.snapshot()))
    twin.adg = restored
    _same_after_more(live, planner, twin, twin_planner, t)


@pytest.mark.parametrize("seed", [1, 2])
def test_task_pool_snapshot_round_trip(seed: int) -> None:
    live, planner, twin, twin_planner, t = _twins(seed)
    pool = live.pool
    snap = pool.snapshot()
    restored = TaskPool(pool.task_list, pool.reveal, leg=twin.pool.leg, keep=pool.keep)
    restored.restore_snapshot(
        copy.deepcopy(snap.pop("live")), ended=copy.deepcopy(OrderedDict(pool.ended)),
        keys=copy.deepcopy(OrderedDict(pool.submissions)), events=copy.deepcopy(pool.events),
        **_json(snap))
    assert state(restored) == state(pool)
    twin.pool = twin.book.pool = restored
    _same_after_more(live, planner, twin, twin_planner, t)


@pytest.mark.parametrize("seed", [1, 2])
def test_lifelong_executor_snapshot_round_trip(seed: int) -> None:
    live, planner, twin, twin_planner, t = _twins(seed)
    restored = _executor(seed, twin.pool)
    restored.distances = twin.distances
    restored.adg, restored.book = twin.adg, twin.book
    restored.restore(**_json(live.snapshot()), outstanding=twin.outstanding)
    _same_after_more(live, planner, restored, twin_planner, t)


def test_a_started_executor_refuses_a_snapshot() -> None:
    live, *_ = _twins(1)
    with pytest.raises(Exception, match="not started yet"):
        live.restore(**_json(live.snapshot()), outstanding=None)
