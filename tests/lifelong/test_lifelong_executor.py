"""The sans-I/O lifelong executor, driven by a small discrete-event loop
(:mod:`sim_clients.shift_des`): robots run what they are dispatched with jittered durations and
random stops, the planner answers after a random latency (so segments arrive while robots
move), and the independent trace checker re-derives the ADG from the trace and replays
occupancy."""

from __future__ import annotations

import dataclasses
from typing import Any

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from gateway.execution.commands import Dispatch, Trigger
from gateway.execution.errors import ExecutionError
from gateway.execution.lifelong.errands import TaskDistances
from gateway.execution.lifelong.executor import (
    LifelongExecutor,
    PlanRequest,
    Segment,
    WindowPlanner,
)
from gateway.execution.lifelong.tasks import TaskPool
from sim_clients.shift_des import ShiftRun, drive_shift
from tests.lifelong.support import small_problem
from tracecheck import check_trace


class _NoDeps(LifelongExecutor):
    """A broken executor for the negative control: it forgets every Type 2 dependency."""

    def adopt(self, segment: Segment, now_ms: float) -> None:
        super().adopt(segment, now_ms)
        for q in self.adg.queue:
            for i, a in enumerate(q):
                q[i] = dataclasses.replace(a, dep_robot=-1)


def drive(seed: int, *, robots: int = 10, size: int = 12, **kw: Any) -> ShiftRun:
    """:func:`~sim_clients.shift_des.drive_shift` on a random ``size`` x ``size`` map."""
    return drive_shift(small_problem(seed, robots=robots, size=size, p_delay=0.0), seed, **kw)


@pytest.mark.parametrize("turning", [True, False])
def test_a_shift_finishes_tasks_without_collisions(turning: bool) -> None:
    run = drive(3, turning=turning)
    report = check_trace(run.records)
    assert report.ok, (report.errors[:5], report.collisions[:5])
    assert run.ex.finished_tasks >= 10
    assert len(run.dispatched) == len(set(run.dispatched))  # no action id twice
    assert run.ex.segments > 20
    assert run.moving_at_adoption > 10  # segments joined while robots were moving
    assert report.actions_run == sum(1 for r in run.records if r["type"] == "finish")


def test_the_negative_control_collides() -> None:
    """Without Type 2 dependencies the same drive breaks the checker: it can fail."""
    run = drive(3, executor=_NoDeps, stop_p=0.2)
    report = check_trace(run.records)
    assert not report.ok


@settings(max_examples=8, deadline=None)
@given(seed=st.integers(0, 10_000), lookahead=st.integers(0, 2),
       latency=st.floats(0.0, 2500.0), jitter=st.floats(0.0, 0.9),
       turning=st.booleans())
def test_property_no_collision_no_duplicate_under_any_timing(
        seed: int, lookahead: int, latency: float, jitter: float, turning: bool) -> None:
    run = drive(seed, robots=8, size=10, horizon_ms=15_000.0, latency_ms=latency,
                jitter=jitter, lookahead=lookahead, turning=turning)
    report = check_trace(run.records)
    assert report.ok, (report.errors[:5], report.collisions[:5])
    assert len(run.dispatched) == len(set(run.dispatched))
    held = max((r["action"] for r in run.records if r["type"] == "dispatch"), default=-1)
    assert held >= 0


def test_reports_are_checked() -> None:
    prob = small_problem(1, robots=4, size=8, p_delay=0.0)
    ex = LifelongExecutor(prob.grid, prob.starts, [0] * 4,
                          TaskPool(prob.tasks, 6), distances=TaskDistances(prob.grid))
    with pytest.raises(ExecutionError, match="not started"):
        ex.tick(0.0)
    ex.start(0.0)
    req = next(c for c in ex.drain() if isinstance(c, PlanRequest))
    seg = WindowPlanner(prob.grid, 4, True)(req)
    with pytest.raises(ExecutionError, match="no planner call 5"):
        ex.adopt(Segment(5, seg.states, seg.reached), 10.0)
    bad = [list(row) for row in seg.states]
    bad[1][0], bad[1][1] = bad[0][1], bad[0][0]  # two robots swap cells in one step
    with pytest.raises(ExecutionError):
        ex.adopt(Segment(req.call, bad, seg.reached), 10.0)
    ex.adopt(seg, 10.0)
    sent = [c for c in ex.drain() if isinstance(c, Dispatch)]
    assert sent
    d = sent[0]
    with pytest.raises(ExecutionError, match="has not started"):
        ex.finished(d.robot, d.plan, d.action, 20.0)
    with pytest.raises(ExecutionError, match="belongs to segment"):
        ex.started(d.robot, d.plan + 1, d.action, 20.0)
    with pytest.raises(ExecutionError, match="not dispatched"):
        ex.started(d.robot, d.plan, d.action + 5, 20.0)
    ex.started(d.robot, d.plan, d.action, 20.0)
    with pytest.raises(ExecutionError, match="time went backwards"):
        ex.finished(d.robot, d.plan, d.action, 19.0)
    with pytest.raises(ExecutionError, match="no cancel"):
        ex.cancelled(d.robot, d.plan, d.action, 30.0)
    ex.finished(d.robot, d.plan, d.action, 1020.0)
    with pytest.raises(ExecutionError, match="finished"):
        ex.finished(d.robot, d.plan, d.action, 1030.0)


def test_long_stops_trigger_an_early_planning_call() -> None:
    run = drive(3, stop_p=0.05, stop_ms=(6000.0, 12000.0))
    triggers = [r for r in run.records if r["type"] == "trigger"]
    assert triggers and all(r["fleet_slack_ms"] > 2000.0 for r in triggers)
    assert run.ex.calls > 40  # one call per second of the 40 s shift, plus the early ones
    assert check_trace(run.records).ok
    quiet = drive(3, stop_p=0.05, stop_ms=(6000.0, 12000.0), threshold_ms=None)
    assert not any(r["type"] == "trigger" for r in quiet.records)


def test_operator_plan_now_and_a_threshold_switched_on_later() -> None:
    prob = small_problem(2, robots=6, size=10, p_delay=0.0)
    records: list[dict[str, Any]] = []
    ex = LifelongExecutor(prob.grid, prob.starts, [0] * 6, TaskPool(prob.tasks, 9),
                          distances=TaskDistances(prob.grid), record=records.append)
    planner = WindowPlanner(prob.grid, 6, True)
    ex.start(0.0)
    req = next(c for c in ex.drain() if isinstance(c, PlanRequest))
    with pytest.raises(ExecutionError, match="a planner call is running"):
        ex.plan_now(5.0)
    ex.adopt(planner(req), 10.0)
    ex.drain()
    ex.plan_now(20.0)  # long before the period is over
    out = ex.drain()
    assert any(isinstance(c, Trigger) and c.policy == "operator" for c in out)
    req2 = next(c for c in out if isinstance(c, PlanRequest))
    assert req2.call == 1 and records[-1]["type"] == "trigger"
    ex.adopt(planner(req2), 30.0)
    ex.threshold_ms = 2000.0  # off at the start: Δ0 is taken at the next check
    ex.tick(600.0)
    assert ex.fleet_slack_ms == 0.0
    ex.tick(1200.0)
    assert ex.fleet_slack_ms >= 0.0


def test_a_restarted_planner_answers_as_the_first_would() -> None:
    # PIBT's priorities go out with each request and come back with each adopted segment,
    # and a call's random stream is its own: a fresh planner (a restarted planner process)
    # answers the executor's next request exactly as the one that answered the earlier calls
    prob = small_problem(4, robots=8, size=10, p_delay=0.0)
    ex = LifelongExecutor(prob.grid, prob.starts, [0] * 8, TaskPool(prob.tasks, 12),
                          distances=TaskDistances(prob.grid))
    first = WindowPlanner(prob.grid, 8, True, seed=3)
    ex.start(0.0)
    for k in range(1, 7):
        req = next(c for c in ex.drain() if isinstance(c, PlanRequest))
        seg = first(req)
        assert seg == WindowPlanner(prob.grid, 8, True, seed=3)(req)
        ex.adopt(seg, 1000.0 * k - 990.0)
        assert ex.priorities == list(seg.priorities)
        ex.tick(1000.0 * k)  # the next call is due
    assert any(req.priorities)  # the later calls start from priorities of their own
