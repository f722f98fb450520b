"""The discrete-event simulator: exact undelayed execution, safety and liveness under random
delays, intruders and replans (checked from the trace by the independent trace checker), and
determinism."""

from __future__ import annotations

import dataclasses
import random

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from gateway.execution.trace_records import Record
from gateway.planning.plan import Plan
from gateway.planning.random_plans import open_grid, random_plan
from sim_clients.des import (
    PolicyName,
    SimConfig,
    SimResult,
    Simulation,
    SimulationError,
    run_simulation,
)
from sim_clients.intruder import IntruderConfig
from tests.execution.support import delayed_plans
from tracecheck import check_trace


def traced(config: SimConfig) -> tuple[SimResult, list[Record]]:
    """Run with an in-memory trace."""
    records: list[Record] = []
    result = run_simulation(dataclasses.replace(config, trace=records.append))
    return result, records


@st.composite
def scenarios(draw: st.DrawFn) -> tuple[SimConfig, dict[tuple[int, int], int]]:
    """A random plan on a small open grid, random per-action delays, a random intruder and a
    random policy (low slack thresholds too, so that replans happen often)."""
    grid, plan, delays = draw(delayed_plans(1, 3))
    appear = draw(st.integers(0, 3000))
    intruder = IntruderConfig(appear_ms=appear, leave_ms=appear + draw(st.integers(1000, 12000)),
                              lead_ms=draw(st.sampled_from([0, 1000, 2000])))
    config = SimConfig(
        grid, plan, seed=draw(st.integers(0, 1000)),
        intruder=draw(st.sampled_from([True, True, False])),
        policy=draw(st.sampled_from(["none", "random", "slack", "informed", "shadow"])),
        threshold_ms=draw(st.sampled_from([0, 500, 2000])), solver_time="zero",
        # a vanishing planner time limit makes replans fail: execution resumes the old plan
        solver_time_limit_s=draw(st.sampled_from([5.0, 5.0, 1e-9])), intruder_config=intruder,
        extra_delay=lambda plan_id, robot, action: float(delays.get((robot, action), 0)),
        stall_ms=120_000.0)
    return config, delays


@settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(scenarios())
def test_random_delays_intruders_and_replans_stay_safe_and_finish(
        scenario: tuple[SimConfig, dict[tuple[int, int], int]]) -> None:
    config, delays = scenario
    result, records = traced(config)  # returning at all means the run terminated
    report = check_trace(records)
    assert report.errors == []  # precedence, exactly-once, plan continuity, summary
    assert report.collisions == []
    assert result.collisions == 0
    # the ADG alone keeps robots apart: only the intruder ever makes a robot wait for a cell
    assert result.robot_blocks == 0
    assert (report.soc_ms, report.makespan_ms) == (result.soc_ms, result.makespan_ms)
    assert report.plans == 1 + result.replans
    for t, recorded, recomputed in report.triggers:  # the monitor's slack, recomputed
        assert recorded == pytest.approx(recomputed, abs=1e-6), t
    if not config.intruder and not delays and result.replans == 0:
        # (a replan may find a better plan than the random walk: then the cost is another)
        assert result.soc_ms == 1000 * config.plan.soc
        assert result.makespan_ms == 1000 * config.plan.makespan


def test_delays_only_add_time_and_undelayed_runs_are_exact() -> None:
    # robot 0 walks 3 cells right; robot 1 comes up to (0,0), waits, then enters (1,0), the
    # cell robot 0 left in its action 0 (ADG edge a_0^0 -> a_3^1). Undelayed: SOC 3000 + 5000.
    grid = open_grid(5, 2)
    plan = Plan.of([[(1, 0), (2, 0), (3, 0), (4, 0)],
                    [(0, 1), (0, 1), (0, 0), (0, 0), (1, 0), (1, 1)]])
    base = SimConfig(grid, plan, intruder=False, solver_time="zero")
    result, _ = traced(base)
    assert (result.soc_ms, result.makespan_ms) == (8000, 5000)
    # 2500 ms more on robot 0's action 0: it ends at 3500, then 4500, 5500. Robot 1's action 3
    # was due at 3000 but waits for it until 3500, so robot 1 ends at 5500 instead of 5000.
    delayed = dataclasses.replace(
        base, extra_delay=lambda p, robot, action: 2500.0 if (robot, action) == (0, 0) else 0.0)
    result, records = traced(delayed)
    assert check_trace(records).ok
    assert (result.soc_ms, result.makespan_ms) == (5500 + 5500, 5500)
    assert result.robot_blocks == 0


def test_same_seed_and_zero_solver_time_are_reproducible() -> None:
    grid = open_grid(6, 5)
    plan = random_plan(grid, 6, 14, random.Random(3))
    policies: tuple[PolicyName, ...] = ("none", "random", "slack")
    for policy in policies:
        config = SimConfig(grid, plan, seed=11, intruder=True, policy=policy,
                           threshold_ms=0.0, solver_time="zero",
                           intruder_config=IntruderConfig(appear_ms=1000, leave_ms=6000))
        first, trace1 = traced(config)
        second, trace2 = traced(config)
        assert first == second
        assert trace1 == trace2
        assert any(r["type"] == "intruder" for r in trace1)


def test_a_deadlock_is_reported_not_looped_on() -> None:
    # a swap is not 1-robust: the ADG orders nothing, both robots wait for each other's cell
    plan = Plan.of([[(0, 0), (1, 0)], [(1, 0), (0, 0)]])
    config = SimConfig(open_grid(2, 1), plan, intruder=False, stall_ms=5000.0)
    with pytest.raises(SimulationError, match="deadlock"):
        run_simulation(config)


def test_bad_configs_are_refused() -> None:
    plan = Plan.of([[(0, 0), (1, 0)]])
    with pytest.raises(ValueError, match="policy"):
        SimConfig(open_grid(2, 1), plan, policy="sometimes")  # type: ignore[arg-type]
    with pytest.raises(ValueError, match=r"visits \(1, 0\)"):
        SimConfig(open_grid(1, 1), plan)
    with pytest.raises(ValueError, match="solver time"):
        SimConfig(open_grid(2, 1), plan, solver_time="later")  # type: ignore[arg-type]


def test_an_abandoned_replan_resumes_the_old_plan() -> None:
    # a slack trigger while the intruder blocks a robot cancels that robot's action; the
    # planner gets no time, so the executor resumes plan 0 and dispatches the action again
    grid = open_grid(5, 5)
    for seed in (0, 1, 2):
        plan = random_plan(grid, 7, 14, random.Random(seed))
        config = SimConfig(grid, plan, seed=seed, policy="slack", threshold_ms=0.0,
                           solver_time="zero", solver_time_limit_s=1e-9,
                           intruder_config=IntruderConfig(appear_ms=1000, leave_ms=8000))
        result, records = traced(config)
        cancels = [(r["robot"], r["action"]) for r in records if r["type"] == "cancel"]
        assert cancels and result.replans == 0 and result.replan_at_ms is not None
        redispatched = [(r["robot"], r["action"]) for r in records
                        if r["type"] == "dispatch" and (r["robot"], r["action"]) in cancels]
        assert len(redispatched) == 2 * len(cancels)
        report = check_trace(records)
        assert report.ok, report.errors
        assert report.actions_run == sum(len(p) - 1 for p in plan.paths)


def test_a_fork_goes_on_exactly_as_the_run_it_was_forked_from() -> None:
    # A forked run must keep the monitor's numpy views on its own flat arrays: fleet slack
    # (numpy maxima) reads them and the compiled propagation writes them. The fork, taken at
    # 2 s, is compared tick by tick with a fresh run.
    grid = open_grid(6, 5)
    plan = random_plan(grid, 7, 14, random.Random(5))
    config = SimConfig(grid, plan, seed=3, policy="slack", threshold_ms=500.0,
                       solver_time="zero",
                       intruder_config=IntruderConfig(appear_ms=1000, leave_ms=7000),
                       extra_delay=lambda p, robot, action: 1500.0 if action == 2 else 0.0)
    fresh, forked = Simulation(config), Simulation(config)
    fresh.start()
    forked.start()
    forked.run_until(2000.0)
    fork = forked.fork()
    seen_slack = set()
    for t in range(2100, 30_000, 100):
        fresh.run_until(float(t))
        fork.run_until(float(t))
        if fresh.finished() or fork.finished():
            break
        a, b = fresh.executor.monitor, fork.executor.monitor
        assert (b.fleet_slack(), b.snapshot()) == (a.fleet_slack(), a.snapshot()), t
        seen_slack.add(a.fleet_slack())
    assert len(seen_slack) > 2  # the slack moved while the two were compared
    fresh.run_until(None)
    fork.run_until(None)
    assert fork.result() == fresh.result()
