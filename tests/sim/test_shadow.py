"""Shadow planning in the simulator and its estimates: a solve the executor does not adopt
changes nothing; an adopted one replans around the block the robots reported, safely; the
forecast with held actions is Algorithm 1's."""

from __future__ import annotations

import dataclasses
import math
import random

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from gateway.execution.commands import SolveRequest
from gateway.execution.errors import ExecutionError
from gateway.execution.oneshot.adg import ADG
from gateway.execution.oneshot.executor import Executor
from gateway.execution.oneshot.monitor import Monitor, algorithm1
from gateway.execution.oneshot.policies import ShadowPolicy
from gateway.execution.oneshot.shadow import forecast_completions
from gateway.execution.trace_records import Record
from gateway.planning.generators import random_instance
from gateway.planning.movingai import read_map
from gateway.planning.plan import Plan
from gateway.planning.random_plans import open_grid, random_plan
from gateway.planning.solver import solve
from gateway.runtime.deadline import WallDeadline
from gateway.runtime.mapstore import resolve
from sim_clients.des import SimConfig, SimResult, Simulation
from sim_clients.intruder import IntruderConfig
from tests.execution.support import random_robust_plan
from tracecheck import check_trace


class _Recording(Simulation):
    """A simulation that keeps every shadow solve request and its answer."""

    def __init__(self, config: SimConfig) -> None:
        super().__init__(config)
        self.shadows: list[tuple[float, SolveRequest]] = []

    def shadow_solve(self, request: SolveRequest, now: float) -> None:
        self.shadows.append((now, request))
        super().shadow_solve(request, now)


def _run(config: SimConfig, policy: ShadowPolicy | None = None
         ) -> tuple[_Recording, SimResult, list[Record]]:
    records: list[Record] = []
    sim = _Recording(dataclasses.replace(config, trace=records.append))
    if policy is not None:
        sim.executor.policy = policy
    return sim, sim.run(), records


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(w=st.integers(3, 6), h=st.integers(3, 6), seed=st.integers(0, 2**32 - 1),
       appear=st.integers(0, 3000), stay=st.integers(1000, 9000))
def test_a_shadow_plan_never_adopted_costs_the_fleet_nothing(w: int, h: int, seed: int,
                                                            appear: int, stay: int) -> None:
    grid = open_grid(w, h)
    plan = random_plan(grid, max(1, w * h // 4), 10, random.Random(seed))
    config = SimConfig(grid, plan, seed=seed % 1000, policy="shadow", solver_time="zero",
                       intruder_config=IntruderConfig(appear_ms=appear,
                                                      leave_ms=appear + stay, lead_ms=0))
    never = ShadowPolicy(margin_ms=math.inf, period_ms=300, min_slack_ms=0)
    sim, shadowed, _ = _run(config, never)
    _, plain, _ = _run(dataclasses.replace(config, policy="none"))
    assert shadowed.replans == 0 and shadowed.replan_at_ms is None
    assert (shadowed.soc_ms, shadowed.makespan_ms, shadowed.end_ms) == \
        (plain.soc_ms, plain.makespan_ms, plain.end_ms)
    if plain.intruder_on_ms is not None and plain.soc_ms > 1000 * plan.soc:
        assert sim.shadows  # delayed: it did solve in the background


def test_shadow_replans_around_the_reported_block_and_pays() -> None:
    grid = read_map(resolve("lab", "map"))
    adopted = 0
    for k in range(8):
        inst = random_instance(grid, 10, np.random.default_rng(k))
        plan = solve(grid, inst.starts, inst.goals, deadline=WallDeadline(20)).plan
        config = SimConfig(grid=grid, plan=plan, seed=k, policy="shadow", solver_time="zero",
                           block_history=(5100.0,))
        sim, res, records = _run(config)
        report = check_trace(records)
        assert report.errors == [] and report.collisions == []
        assert res.collisions == 0 and res.robot_blocks == 0
        _, plain, _ = _run(dataclasses.replace(config, policy="none"))
        if res.replans == 0:
            assert res.soc_ms == plain.soc_ms
            continue
        adopted += 1
        trigger, = (r for r in records if r["type"] == "trigger")
        assert trigger["policy"] == "shadow"
        # the replan was decided when a background solve came back, with no solve after it
        decided = [now for now, _ in sim.shadows if now <= trigger["t_ms"]]
        assert decided and sim.shadows[len(decided) - 1][1].obstacles
        cell = tuple(next(r for r in records if r["type"] == "intruder")["cell"])
        assert all(c == cell for c, _ in sim.shadows[len(decided) - 1][1].obstacles)
        assert res.soc_ms < plain.soc_ms
    assert adopted >= 2


def test_a_shadow_plan_for_where_the_fleet_no_longer_stops_is_dropped() -> None:
    # robot 0 walks two cells east, robot 1 waits a second; any plan would be adopted
    plan = Plan.of([[(0, 0), (1, 0), (2, 0)], [(1, 1), (1, 1)]])
    ex = Executor(plan, policy=ShadowPolicy(margin_ms=-math.inf, min_slack_ms=0))
    ex.start(0.0)
    ex.drain()
    with pytest.raises(ExecutionError, match="no shadow solve"):
        ex.shadow_solved(None, 0.0)
    ex.tick(0.0)
    (request,) = [c for c in ex.drain() if isinstance(c, SolveRequest)]
    assert request.shadow and request.starts == ((0, 0), (1, 1))
    ex.started(0, 0, 0, 10.0)  # robot 0 moves on: it would now stop on (1,0)
    assert not ex.shadow_solved(Plan.of([[(0, 0), (1, 0), (2, 0)], [(1, 1)]]), 20.0)
    assert ex.replans == 0 and ex.drain() == []


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 10**6), robots=st.integers(1, 5), hold=st.integers(0, 5000),
       which=st.integers(0, 10**6))
def test_forecast_with_a_held_first_action_is_algorithm1_with_a_later_release(
        seed: int, robots: int, hold: int, which: int) -> None:
    paths = random_robust_plan(seed, 4, 4, robots, 8)
    adg = ADG(Plan.of(paths))
    robot = which % robots
    v = adg.first[robot]
    if adg.first[robot + 1] == v:
        return  # the robot has no action
    monitor = Monitor(adg, now_ms=0.0, action_ms=1000.0)
    got = forecast_completions(monitor, {v: float(hold)})
    release = [0.0] * robots
    release[robot] = float(hold)
    nv = adg.n_vertices
    want = algorithm1(adg, now_ms=0.0, action_ms=1000.0, release_ms=release,
                      started_ms=[None] * nv, finished_ms=[None] * nv)
    for r in range(robots):
        last = adg.first[r + 1] - 1
        assert got[r] == (want.tc[last] if last >= adg.first[r] else 0.0)
