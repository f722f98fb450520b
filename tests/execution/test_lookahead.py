"""Lookahead dispatch: queued actions are released once their Type 2 edges are done, a queued
action may start only after its predecessor finished, replans cancel queued actions, and whole
random executions with robot queues stay correct (support.Driver's oracles, queue-playing robots).
"""

from __future__ import annotations

from collections import deque

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from gateway.execution.commands import Cancel, Dispatch, SolveRequest, Trigger
from gateway.execution.oneshot.executor import ExecutionError, Executor, Mode
from gateway.execution.oneshot.policies import OperatorOnly, SlackReplan
from gateway.planning.plan import Plan
from tests.execution.support import Driver, random_robust_plan, snapshot
from tests.execution.test_adg import CORRIDOR, CROSSING
from tests.execution.test_properties import _kept, check_replanned_run, plans

A, B = 0, 1


def _dispatches(ex: Executor) -> list[tuple[int, int]]:
    return [(c.robot, c.action) for c in ex.drain() if isinstance(c, Dispatch)]


def test_queued_dispatch_waits_for_type2_edges_only() -> None:
    # CROSSING: A (0,1)->(1,1)->(2,1); B waits twice on (1,0), then enters (1,1) (a_2, Type 2
    # edge from A's a_1, which leaves (1,1)) and goes on to (1,2) (a_3).
    ex = Executor(Plan.of(CROSSING), lookahead=1)
    ex.start(0)
    # each robot gets its first action and one more: no Type 2 edge into A1 or B1
    assert _dispatches(ex) == [(A, 0), (A, 1), (B, 0), (B, 1)]
    ex.started(A, 0, 0, 0)
    ex.started(B, 0, 0, 0)
    ex.finished(B, 0, 0, 1000)
    assert _dispatches(ex) == []  # B holds B1; B2 waits for A1 (Type 2) anyway
    ex.started(B, 0, 1, 1000)
    ex.finished(A, 0, 0, 1000)
    ex.started(A, 0, 1, 1000)
    ex.finished(B, 0, 1, 2000)
    assert _dispatches(ex) == []  # B is idle, but A1 has not finished: B2 stays back
    ex.finished(A, 0, 1, 2000)
    assert _dispatches(ex) == [(B, 2), (B, 3)]  # B2 released, B3 queued behind it
    ex.started(B, 0, 2, 2000)
    ex.finished(B, 0, 2, 3000)
    ex.started(B, 0, 3, 3000)
    ex.finished(B, 0, 3, 4000)
    assert ex.done and (ex.soc_ms, ex.makespan_ms) == (2000 + 4000, 4000)


def test_lookahead_n_queues_up_to_n_actions_behind_the_current_one() -> None:
    # CORRIDOR: red (0) drives 4 cells right; blue (1) waits, then follows into the cells red
    # left: blue's a_1 has a Type 2 edge from red's a_0.
    ex = Executor(Plan.of(CORRIDOR), lookahead=2)
    ex.start(0)
    assert _dispatches(ex) == [(0, 0), (0, 1), (0, 2), (1, 0)]
    ex.started(0, 0, 0, 0)
    ex.finished(0, 0, 0, 1000)
    assert _dispatches(ex) == [(0, 3), (1, 1)]  # red refills; blue's a_1 is now released
    ex.started(1, 0, 0, 1000)  # blue's wait a_0 (a robot may start late)
    assert _dispatches(ex) == []  # blue already holds a_0, a_1; a_2 waits for red's a_1


def test_a_queued_action_cannot_start_before_its_predecessor_finished() -> None:
    ex = Executor(Plan.of(CROSSING), lookahead=1)
    ex.start(0)
    ex.drain()
    ex.started(A, 0, 0, 0)
    before = snapshot(ex)
    for event in (ex.started, ex.finished, ex.blocked):
        with pytest.raises(ExecutionError, match="queued behind action 0, which has not fin"):
            event(A, 0, 1, 500)
    assert snapshot(ex) == before  # nothing changed
    with pytest.raises(ExecutionError, match="no Cancel is outstanding"):
        ex.cancelled(A, 0, 1, 500)
    ex.finished(A, 0, 0, 1000)
    ex.started(A, 0, 1, 1000)  # now it may


def test_lookahead_zero_never_dispatches_before_the_predecessor_finished() -> None:
    ex = Executor(Plan.of(CROSSING))
    ex.start(0)
    assert _dispatches(ex) == [(A, 0), (B, 0)]
    with pytest.raises(ExecutionError, match="lookahead must be >= 0"):
        Executor(Plan.of(CROSSING), lookahead=-1)


def test_replan_cancels_queued_actions_and_solves_only_when_all_are_confirmed() -> None:
    ex = Executor(Plan.of(CROSSING), policy=OperatorOnly(), lookahead=1)
    ex.start(0)
    ex.drain()
    ex.started(A, 0, 0, 0)
    ex.request_replan(300)
    # A's queued a_1 and both of B's (dispatched, not started) actions are cancelled
    assert ex.drain() == [Trigger("operator", 0.0), Cancel(0, A, 1), Cancel(0, B, 0),
                          Cancel(0, B, 1)]
    ex.finished(A, 0, 0, 1000)
    ex.cancelled(B, 0, 0, 1000)
    # B confirmed its current action only: a queued action may not start without it
    with pytest.raises(ExecutionError, match="predecessor action 0 has not finished"):
        ex.started(B, 0, 1, 1000)
    ex.cancelled(B, 0, 1, 1000)
    assert ex.drain() == [] and ex.mode is Mode.STOPPING  # A's queued a_1 is not confirmed
    ex.cancelled(A, 0, 1, 1100)
    assert ex.drain() == [SolveRequest(((1, 1), (1, 0)), ((2, 1), (1, 2)))]
    # the solver fails: the old plan resumes, the cancelled actions are dispatched again
    ex.abandon_replan(1200)
    assert _dispatches(ex) == [(A, 1), (B, 0), (B, 1)]


def test_the_monitor_does_not_see_the_lookahead() -> None:
    # the same starts and finishes give the same estimates with and without lookahead
    events = [("started", A, 0, 0), ("started", B, 0, 100), ("finished", A, 0, 1200),
              ("started", A, 1, 1300), ("finished", B, 0, 1400), ("started", B, 1, 1400)]
    estimates = []
    for lookahead in (0, 1):
        ex = Executor(Plan.of(CROSSING), lookahead=lookahead)
        ex.start(0)
        for kind, robot, action, t in events:
            getattr(ex, kind)(robot, 0, action, t)
            ex.tick(t)
        estimates.append(snapshot(ex.monitor.snapshot()))
    assert estimates[0] == estimates[1]


class QueueDriver(Driver):
    """support.Driver whose robots hold a queue: dispatches are checked against the lookahead
    release rule, each robot runs its queue strictly in order (the next action is taken up when
    the current one finishes), and a cancel drops the action and everything queued behind it
    (unless it is the current one and the robot already began; sometimes it begins anyway)."""

    def __init__(self, ex: Executor, seed: int, **kwargs: object) -> None:
        super().__init__(ex, seed, **kwargs)  # type: ignore[arg-type]
        self.held: list[deque[tuple[int, int]]] = [deque() for _ in ex.plan.paths]
        self.max_held = 0

    def _on_dispatch(self, cmd: Dispatch, now: float) -> None:
        log, r = self.plans[cmd.plan], cmd.robot
        key = (r, cmd.action)
        assert cmd.plan == len(self.plans) - 1 and key not in log.started
        held = self.held[r]
        for p in log.preds[key]:
            if p[0] == r:  # Type 1: finished, or queued on this robot
                assert p in log.finished or (cmd.plan, p[1]) in held, "Type 1 not dispatched"
            else:
                assert p in log.finished, "dispatched before a Type 2 predecessor finished"
        assert not held or (cmd.plan, cmd.action) > held[-1], "robot's actions out of order"
        held.append((cmd.plan, cmd.action))
        assert len(held) <= 1 + self.ex.lookahead
        self.max_held = max(self.max_held, len(held))
        log.dispatched.append(key)
        if len(held) == 1:
            self._begin(r, cmd.plan, cmd.action, now)

    def _on_cancel(self, cmd: Cancel, now: float) -> None:
        held = self.held[cmd.robot]
        if (cmd.plan, cmd.action) not in held:
            return  # dropped already with an earlier one
        pos = held.index((cmd.plan, cmd.action))
        if pos == 0:
            if self.robot_begun[cmd.robot] or self.rng.random() >= 0.8:
                return  # it runs on (or begins anyway): its queue is cancelled separately
            self.robot_token[cmd.robot] += 1
        for plan_id, action in list(held)[pos:]:
            self._at(now + self.rng.choice([0, 50]), "cancelled", cmd.robot, plan_id, action,
                     self.robot_token[cmd.robot])
        while len(held) > pos:
            held.pop()

    def _apply(self, t: float, kind: str, args: tuple[object, ...]) -> None:
        if kind == "start":
            robot, plan_id, action, token = args
            assert isinstance(robot, int) and isinstance(plan_id, int) and isinstance(action, int)
            if token == self.robot_token[robot]:
                log = self.plans[plan_id]
                missing = [p for p in log.preds[(robot, action)] if p not in log.finished]
                assert not missing, f"{(robot, action)} starts before {missing} finished"
        super()._apply(t, kind, args)
        if kind == "finish":
            robot, plan_id, action, token = args
            assert isinstance(robot, int) and isinstance(plan_id, int)
            if token == self.robot_token[robot]:
                held = self.held[robot]
                assert held.popleft() == (plan_id, action)
                if held:
                    self._begin(robot, *held[0], t)


@settings(max_examples=120, deadline=None)
@given(paths=plans(), seed=st.integers(0, 10**6), drop_waits=st.booleans(),
       lookahead=st.sampled_from([1, 1, 2]))
def test_queued_execution_runs_every_action_once_in_order(
        paths: list[list[tuple[int, int]]], seed: int, drop_waits: bool, lookahead: int) -> None:
    plan = Plan.of(paths)
    ex = Executor(plan, drop_waits=drop_waits, lookahead=lookahead)
    driver = QueueDriver(ex, seed)
    done = driver.run()  # returning means it terminated
    (log,) = driver.plans
    assert set(log.started) == set(log.finished) == _kept(plan, drop_waits)
    assert sorted(log.dispatched) == sorted(log.finished)  # dispatched once each
    last = [max((t for (r, _), t in log.finished.items() if r == k), default=0.0)
            for k in range(len(plan.paths))]
    assert (done.soc_ms, done.makespan_ms) == (sum(last), max(last, default=0.0))


@settings(max_examples=120, deadline=None)
@given(paths=plans(), seed=st.integers(0, 10**6), drop_waits=st.booleans(),
       replan_at=st.integers(0, 8000), max_replans=st.integers(1, 3),
       abandon=st.sampled_from([0.0, 0.5]), slack=st.booleans())
def test_queued_execution_with_replans_terminates_and_stays_consistent(
        paths: list[list[tuple[int, int]]], seed: int, drop_waits: bool, replan_at: int,
        max_replans: int, abandon: float, slack: bool) -> None:
    plan = Plan.of(paths)
    policy = SlackReplan(500) if slack else None
    ex = Executor(plan, drop_waits=drop_waits, max_replans=max_replans, policy=policy,
                  lookahead=1)
    driver = QueueDriver(ex, seed, replan_at_ms=replan_at, abandon_prob=abandon)
    check_replanned_run(ex, driver, plan, drop_waits, max_replans)


def test_the_queue_driver_really_queues_and_replans() -> None:
    # guards the property tests above against a driver that never holds two actions
    for seed in range(3):
        ex = Executor(Plan.of(random_robust_plan(seed, 5, 4, 6, 12)), lookahead=1,
                      policy=OperatorOnly())
        driver = QueueDriver(ex, seed, replan_at_ms=3000)
        driver.run()
        assert driver.max_held == 2 and ex.replans == 1 and len(driver.plans) == 2
