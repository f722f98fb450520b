"""A lifelong shift in virtual time: the sans-I/O
:class:`~gateway.execution.lifelong.executor.LifelongExecutor` driven by a small discrete-event loop
(robots run what they are dispatched with jittered durations and random stops, the windowed
planner answers after a random latency, so segments arrive while robots move). The lifelong
tests drive their shifts with it, and ``bench/lifelong.py --journal`` a long journaled one.
"""

from __future__ import annotations

import dataclasses
import heapq
import random
from collections import deque
from collections.abc import Callable
from typing import Any

from gateway.execution.commands import Completed, Dispatch, Trigger
from gateway.execution.lifelong.errands import TaskDistances
from gateway.execution.lifelong.executor import LifelongExecutor, PlanRequest, WindowPlanner
from gateway.execution.lifelong.tasks import TaskPool
from gateway.execution.trace_records import summary_record
from gateway.planning.lorr import LorrProblem


@dataclasses.dataclass
class ShiftRun:
    """What a driven shift produced."""

    ex: LifelongExecutor
    records: list[dict[str, Any]]
    dispatched: list[tuple[int, int, int]]
    moving_at_adoption: int
    """Segments adopted while at least one robot was in the middle of an action."""


def drive_shift(prob: LorrProblem, seed: int, *, turning: bool = True,
                horizon_ms: float = 40_000.0, latency_ms: float = 300.0, jitter: float = 0.3,
                stop_p: float = 0.05, stop_ms: tuple[float, float] = (100.0, 3000.0),
                lookahead: int = 1, threshold_ms: float | None = 2000.0, trace: bool = True,
                executor: Callable[..., LifelongExecutor] = LifelongExecutor,
                each: Callable[[LifelongExecutor, float], None] | None = None,
                routed: Callable[[LifelongExecutor, float], None] | None = None) -> ShiftRun:
    """Run a shift of ``prob``'s fleet for ``horizon_ms`` in virtual time, then stop it and
    drain the fleet (the trace records are kept if ``trace``); ``each(ex, t)`` is called
    after every event (e.g. a task API's changes), ``routed(ex, t)`` once the commands that
    followed it are routed."""
    rng = random.Random(seed)
    grid = prob.grid
    robots = prob.team_size
    pool = TaskPool(prob.tasks, max(1, int(prob.num_tasks_reveal * robots)))
    records: list[dict[str, Any]] = []
    ex = executor(grid, prob.starts, [0] * robots if turning else None, pool,
                  distances=TaskDistances(grid), lookahead=lookahead,
                  threshold_ms=threshold_ms, record=records.append if trace else None)
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
        if routed is not None:
            routed(ex, t)
    assert done, "the stopped run never completed"
    if trace:
        records.append(summary_record(sum(ex.completion), max(ex.completion)))
    return ShiftRun(ex, records, dispatched, moving_at_adoption)
