"""Properties of whole executions on random 1-robust plans with random delays and replans.

The test-local discrete-event loop (support.Driver) checks after every event that the
incremental monitor equals the full Algorithm 1 recomputation and that Δ̄F / robot slack are the
maxima over not-started actions; at every dispatch that all ADG predecessors (computed by brute
force from the definition) have finished and that the robot's actions come in order.
"""

from __future__ import annotations

from hypothesis import given, settings
from hypothesis import strategies as st

from gateway.execution.oneshot.executor import Executor
from gateway.execution.oneshot.policies import SlackReplan
from gateway.planning.plan import Plan
from tests.execution.support import Driver, random_robust_plan


@st.composite
def plans(draw: st.DrawFn) -> list[list[tuple[int, int]]]:
    """A random 1-robust plan on a small grid (crowded enough for many Type 2 edges)."""
    width, height = draw(st.integers(3, 6)), draw(st.integers(2, 5))
    robots = draw(st.integers(1, min(7, width * height // 2)))
    return random_robust_plan(draw(st.integers(0, 10**6)), width, height, robots,
                              draw(st.integers(1, 14)))



def _kept(plan: Plan, drop_waits: bool) -> set[tuple[int, int]]:
    return {(k, i) for k, p in enumerate(plan.paths) for i in range(len(p) - 1)
            if not (drop_waits and p[i] == p[i + 1])}


@settings(max_examples=150, deadline=None)
@given(paths=plans(), seed=st.integers(0, 10**6), drop_waits=st.booleans())
def test_retiming_runs_every_action_exactly_once_in_order(
        paths: list[list[tuple[int, int]]], seed: int, drop_waits: bool) -> None:
    plan = Plan.of(paths)
    ex = Executor(plan, drop_waits=drop_waits)
    driver = Driver(ex, seed)
    done = driver.run()
    (log,) = driver.plans
    assert set(log.started) == set(log.finished) == _kept(plan, drop_waits)
    assert sorted(log.dispatched) == sorted(log.finished)  # dispatched once each
    last = [max((t for (r, _), t in log.finished.items() if r == k), default=0.0)
            for k in range(len(plan.paths))]
    assert (done.soc_ms, done.makespan_ms) == (sum(last), max(last, default=0.0))
    # actions run one after another: a robot needs at least the driver's shortest move (700 ms)
    # per kept action
    for k in range(len(plan.paths)):
        n = sum(1 for r, _ in _kept(plan, drop_waits) if r == k)
        assert last[k] >= 700 * n


@settings(max_examples=150, deadline=None)
@given(paths=plans(), seed=st.integers(0, 10**6), drop_waits=st.booleans(),
       replan_at=st.integers(0, 8000), max_replans=st.integers(1, 3),
       abandon=st.sampled_from([0.0, 0.5]), slack=st.booleans())
def test_runs_with_replans_terminate_and_stay_consistent(
        paths: list[list[tuple[int, int]]], seed: int, drop_waits: bool, replan_at: int,
        max_replans: int, abandon: float, slack: bool) -> None:
    plan = Plan.of(paths)
    policy = SlackReplan(500) if slack else None
    ex = Executor(plan, drop_waits=drop_waits, max_replans=max_replans, policy=policy)
    driver = Driver(ex, seed, replan_at_ms=replan_at, abandon_prob=abandon)
    check_replanned_run(ex, driver, plan, drop_waits, max_replans)


def check_replanned_run(ex: Executor, driver: Driver, plan: Plan, drop_waits: bool,
                        max_replans: int) -> None:
    """Run ``driver`` to the end and check a run with replans: it terminated within the replan
    budget, each plan ran a prefix of every robot's actions, the last one all of them."""
    done = driver.run()
    assert ex.done and ex.replans <= max_replans
    assert len(driver.triggers) == ex.replans
    final = driver.plans[-1]
    # the final plan ran to the end; every earlier plan ran a prefix of each robot's actions
    assert set(final.finished) == _kept(Plan.of(final.paths), drop_waits)
    for log in driver.plans:
        for k in range(len(plan.paths)):
            mine = sorted(a for (r, a) in log.finished if r == k)
            kept = sorted(a for (r, a) in _kept(Plan.of(log.paths), drop_waits) if r == k)
            assert mine == kept[: len(mine)]
        assert set(log.finished) == set(log.started)
    # every robot ends on its goal; SOC counts the stop and the solver time
    assert [ex.robot_cell(k) for k in range(len(plan.paths))] == [p[-1] for p in plan.paths]
    assert done.soc_ms == sum(driver.last_finish)
