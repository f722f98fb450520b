"""The sans-I/O lifelong executor, driven by a small discrete-event loop in these tests: robots
run what they are dispatched with jittered durations and random stops, the planner answers
after a random latency (so segments arrive while robots move), and the independent trace
checker re-derives the ADG from the trace and replays occupancy."""

from __future__ import annotations

import dataclasses
import heapq
import random
from collections import deque
from collections.abc import Callable
from typing import Any

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from gateway.execution.commands import Completed, Dispatch, Trigger
from gateway.execution.errands import TaskDistances
from gateway.execution.errors import ExecutionError
from gateway.execution.lifelong import LifelongExecutor, PlanRequest, Segment, WindowPlanner
from gateway.execution.tasks import TaskPool
from gateway.execution.trace_records import summary_record
from tests.lifelong.support import small_problem
from tracecheck import check_trace


@dataclasses.dataclass
class Run:
    """What a driven run produced."""

    ex: LifelongExecutor
    records: list[dict[str, Any]]
    dispatched: list[tuple[int, int, int]]
    moving_at_adoption: int
    """Segments adopted while at least one robot was in the middle of an action."""


class _NoDeps(LifelongExecutor):
    """A broken executor for the negative control: it forgets every Type 2 dependency."""

    def adopt(self, segment: Segment, now_ms: float) -> None:
        super().adopt(segment, now_ms)
        for q in self.adg.queue:
            for i, a in enumerate(q):
                q[i] = dataclasses.replace(a, dep_robot=-1)


def drive(seed: int, *, robots: int = 10, size: int = 12, turning: bool = True,
          horizon_ms: float = 40_000.0, latency_ms: float = 300.0, jitter: float = 0.3,
          stop_p: float = 0.05, stop_ms: tuple[float, float] = (100.0, 3000.0),
          lookahead: int = 1, threshold_ms: float | None = 2000.0,
          executor: Callable[..., LifelongExecutor] = LifelongExecutor,
          each: Callable[[LifelongExecutor, float], None] | None = None) -> Run:
    """Run a shift of ``horizon_ms`` in virtual time, then stop it and drain the fleet;
    ``each(ex, t)`` is called after every event (e.g. a task API's changes)."""
    prob = small_problem(seed, robots=robots, size=size, p_delay=0.0)
    rng = random.Random(seed)
    grid = prob.grid
    pool = TaskPool(prob.tasks, max(1, int(1.5 * robots)))
    records: list[dict[str, Any]] = []
    ex = executor(grid, prob.starts, [0] * robots if turning else None, pool,
                  distances=TaskDistances(grid), lookahead=lookahead,
                  threshold_ms=threshold_ms, record=records.append)
    planner = WindowPlanner(grid, robots, turning, seed)
    events: list[tuple[float, int, str, Any]] = []
    order = 0
    queues: list[deque[Dispatch]] = [deque() for _ in range(robots)]
    running: list[Dispatch | None] = [None] * robots
    dispatched: list[tuple[int, int, int]] = []
    moving_at_adoption = 0
    waiting: set[int] = set()  # robots that reported blocked
    done = False

    def push(t: float, kind: str, data: Any) -> None:
        nonlocal order
        order += 1
        heapq.heappush(events, (t, order, kind, data))

    def route(t: float) -> None:
        nonlocal done
        for c in ex.drain():
            if isinstance(c, Dispatch):
                dispatched.append((c.plan, c.robot, c.action))
                queues[c.robot].append(c)
                push(t, "try", c.robot)
            elif isinstance(c, PlanRequest):
                push(t + rng.uniform(0, latency_ms), "adopt", planner(c))
            elif isinstance(c, Completed):
                done = True
            else:
                assert isinstance(c, Trigger)

    ex.start(0.0)
    route(0.0)
    push(100.0, "tick", None)
    stopped = False
    while events and not done:
        t, _, kind, data = heapq.heappop(events)
        if not stopped and t >= horizon_ms:
            ex.stop(t)
            stopped = True
        if kind == "tick":
            ex.tick(t)
            push(t + 100.0, "tick", None)
        elif kind == "adopt":
            moving_at_adoption += any(d is not None for d in running)
            if ex.outstanding is not None:
                ex.adopt(data, t)
        elif kind == "try":
            r = data
            if running[r] is None and queues[r]:
                d = running[r] = queues[r].popleft()
                if rng.random() < stop_p:  # the cell looks taken for a while
                    ex.blocked(r, d.plan, d.action, t)
                    waiting.add(r)
                    push(t + rng.uniform(*stop_ms), "go", r)
                else:
                    push(t, "go", r)
        elif kind == "go":
            d = running[data]
            assert d is not None
            if data in waiting:
                waiting.discard(data)
                ex.unblocked(data, d.plan, d.action, t)
            ex.started(data, d.plan, d.action, t)
            push(t + d.duration_ms * rng.uniform(1 - jitter, 1 + jitter), "finish", data)
        elif kind == "finish":
            d = running[data]
            assert d is not None
            running[data] = None
            ex.finished(data, d.plan, d.action, t)
            push(t, "try", data)
        if each is not None:
            each(ex, t)
        route(t)
    assert done, "the stopped run never completed"
    records.append(summary_record(sum(ex.completion), max(ex.completion)))
    return Run(ex, records, dispatched, moving_at_adoption)


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
