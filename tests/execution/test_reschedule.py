"""Reschedule-first: switched Type 2 edges keep execution collision-free and the graph acyclic
(checked by the independent trace checker), the swapped-in monitor equals a full Algorithm 1
recomputation, and the policy lets others pass a delayed robot."""

from __future__ import annotations

import dataclasses
import random
from collections.abc import Callable

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from gateway.execution.errors import ExecutionError
from gateway.execution.oneshot.adg import ADG
from gateway.execution.oneshot.executor import Executor, Mode
from gateway.execution.oneshot.monitor import Monitor, algorithm1
from gateway.execution.oneshot.policies import make_policy
from gateway.execution.oneshot.reschedule import Rescheduled, Schedule, Search, gains_edges
from gateway.execution.trace_records import Record
from gateway.planning.grid import Cell
from gateway.planning.plan import Plan
from gateway.planning.random_plans import open_grid
from sim_clients.des import SimConfig, Simulation, run_simulation
from sim_clients.intruder import IntruderConfig
from tests.execution.support import brute_type2, delayed_plans, random_robust_plan
from tracecheck import check_trace


@settings(max_examples=60, deadline=None)
@given(st.integers(0, 10_000), st.integers(1, 8), st.booleans())
def test_the_plans_visit_order_gives_exactly_its_type2_edges(seed: int, robots: int,
                                                             drop_waits: bool) -> None:
    paths = random_robust_plan(seed, 5, 4, robots, 10)
    adg = ADG(Plan.of(paths), drop_waits=drop_waits)
    edges = Schedule.of(adg).edges()
    named = sorted((adg.robot_of[t], adg.step_of[t], adg.robot_of[h], adg.step_of[h])
                   for t, h in edges)
    assert named == brute_type2(paths)  # the definition, by brute force over all pairs


def random_switches(rng: random.Random, count: int) -> Search:
    """A search that makes up to ``count`` random allowed switches, whatever they cost."""

    def search(schedule: Schedule, adg: ADG, monitor: Monitor,
               may_gain_edges: Callable[[int], bool],
               holds: dict[int, float]) -> Rescheduled | None:
        switches: list[tuple[Cell, int, int]] = []
        for _ in range(count):
            options = [(c, i) for c, visits in schedule.orders.items()
                       for i in range(len(visits) - 1) if schedule.switchable(c, i)]
            rng.shuffle(options)
            for cell, i in options:
                trial = schedule.switched(cell, i)
                try:
                    graph = adg.with_type2(trial.edges())
                except ExecutionError:
                    continue  # a cycle: refused
                if all(may_gain_edges(v) for v in gains_edges(adg, graph)):
                    visits = schedule.orders[cell]
                    switches.append((cell, visits[i + 1].robot, visits[i].robot))
                    schedule, adg = trial, graph
                    break
        if not switches:
            return None
        return Rescheduled(schedule, adg, monitor.rewired(adg), tuple(switches), 0.0)

    return search


def _acyclic(adg: ADG) -> bool:
    """Kahn's algorithm over the graph's predecessor lists (not its levels)."""
    left = [len(adg.predecessors(v)) for v in range(adg.n_vertices)]
    ready = [v for v in range(adg.n_vertices) if left[v] == 0]
    seen = 0
    while ready:
        v = ready.pop()
        seen += 1
        for w in adg.successors(v):
            left[w] -= 1
            if left[w] == 0:
                ready.append(w)
    return seen == adg.n_vertices


def _check_monitor(ex: Executor, records: list[Record]) -> None:
    """The executor's (rewired) monitor equals Algorithm 1 recomputed on its graph."""
    adg, plan_id = ex.adg, ex.plan_id
    release = next(r["t_ms"] for r in records if r["type"] == "plan" and r["plan"] == plan_id)
    started: dict[tuple[int, int], float] = {}
    finished: dict[tuple[int, int], float] = {}
    for r in records:
        if r.get("plan") == plan_id and r["type"] in ("start", "finish", "cancel"):
            key = (r["robot"], r["action"])
            if r["type"] == "start":
                started[key] = r["t_ms"]
            elif r["type"] == "finish":
                finished[key] = r["t_ms"]
            else:
                started.pop(key, None)
    keys = [(adg.robot_of[v], adg.step_of[v]) for v in range(adg.n_vertices)]
    full = algorithm1(adg, now_ms=ex.monitor.now_ms, action_ms=ex.monitor.tx,
                      release_ms=[release] * adg.n_robots,
                      started_ms=[started.get(k) for k in keys],
                      finished_ms=[finished.get(k) for k in keys])
    got = ex.monitor.snapshot()
    assert (got.ts, got.tc, got.delta) == (full.ts, full.tc, full.delta)


@st.composite
def runs(draw: st.DrawFn) -> tuple[SimConfig, list[float], int]:
    """A random plan with random delays, maybe an intruder and a slack policy, and the times
    at which random switches are made."""
    grid, plan, delays = draw(delayed_plans(2, 4))
    appear = draw(st.integers(0, 3000))
    config = SimConfig(
        grid, plan, seed=draw(st.integers(0, 1000)), intruder=draw(st.booleans()),
        policy=draw(st.sampled_from(["none", "slack"])), threshold_ms=500,
        solver_time="zero", lookahead=draw(st.sampled_from([0, 0, 1])),
        intruder_config=IntruderConfig(appear_ms=appear, leave_ms=appear + 4000),
        extra_delay=lambda plan_id, robot, action: float(delays.get((robot, action), 0)),
        stall_ms=120_000.0)
    times = sorted(draw(st.lists(st.integers(0, 8_000), min_size=1, max_size=6)))
    return config, [float(t) for t in times], draw(st.integers(1, 4))


@settings(max_examples=120, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(runs(), st.integers(0, 2**32 - 1))
def test_any_switches_under_random_delays_never_collide_and_stay_acyclic(
        run: tuple[SimConfig, list[float], int], seed: int) -> None:
    config, times, count = run
    records: list[Record] = []
    sim = Simulation(dataclasses.replace(config, trace=records.append))
    rng = random.Random(seed)
    sim.start()
    switched = 0
    for t in times:
        sim.run_until(t)
        ex = sim.executor
        if sim.finished() or ex.mode is not Mode.RUNNING:
            continue
        sim.now = t
        switched += ex.reschedule(t, search=random_switches(rng, count))
        sim.handle(t)
        assert _acyclic(ex.adg)
        _check_monitor(ex, records)
    sim.run_until(None)
    result = sim.result()
    report = check_trace(records)  # precedence on the switched edges, exactly-once, summary
    assert report.errors == []
    assert report.collisions == []  # the independent collision checker
    assert result.collisions == 0
    assert result.robot_blocks == 0  # the switched ADG alone keeps robots apart
    assert switched == sum(1 for r in records if r["type"] == "reschedule")
    for t, recorded, recomputed in report.triggers:  # slack keeps the plan's own Δ0
        assert recorded == pytest.approx(recomputed, abs=1e-6), t


def test_a_switch_that_closes_a_cycle_is_refused() -> None:
    # Robot 1 follows robot 0 through (1,0) and then (2,0). Letting robot 1 pass (1,0) first
    # while robot 0 still passes (2,0) first would make each wait for the other.
    plan = Plan.of([[(0, 0), (1, 0), (2, 0), (3, 0)],
                    [(1, 1), (1, 1), (1, 1), (1, 0), (2, 0), (2, 1)]])
    adg = ADG(plan)
    schedule = Schedule.of(adg)
    assert [v.robot for v in schedule.orders[(1, 0)]] == [0, 1]
    switched = schedule.switched((1, 0), 0)
    assert [v.robot for v in switched.orders[(1, 0)]] == [1, 0]
    with pytest.raises(ExecutionError, match="cycle"):
        adg.with_type2(switched.edges())
    # switching both cells is fine: robot 1 passes first all along
    both = switched.switched((2, 0), 0)
    assert _acyclic(adg.with_type2(both.edges()))
    assert (0, 0) not in schedule.orders  # only robot 0 visits it


CROSSING = Plan.of([[(0, 1), (1, 1), (2, 1), (3, 1), (4, 1)],
                    [(2, 0), (2, 0), (2, 0), (2, 0), (2, 1), (2, 2)]])
"""Robot 0 crosses (2,1) in its actions 1-2; robot 1 waits above it and enters after."""


def test_the_policy_lets_a_robot_pass_a_delayed_one() -> None:
    # Robot 0's first action takes 6 s instead of 1 s. Without rescheduling robot 1 waits for
    # it to cross (2,1): robot 1 ends at 10 s (robot 0 at 9 s). Switching (2,1) lets robot 1
    # cross first as soon as the estimate says robot 0's wait costs more than robot 1's
    # crossing; robot 0 still ends at 9 s.
    base = SimConfig(open_grid(5, 3), CROSSING, intruder=False, solver_time="zero",
                     extra_delay=lambda p, robot, action: 5000.0 if (robot, action) == (0, 0)
                     else 0.0)
    kept = run_simulation(base)
    assert (kept.soc_ms, kept.reschedules) == (19_000, 0)
    records: list[Record] = []
    switched = run_simulation(dataclasses.replace(base, policy="reschedule",
                                                  trace=records.append))
    assert switched.reschedules == 1 and switched.replans == 0
    assert switched.soc_ms < kept.soc_ms
    assert switched.makespan_ms == 9000  # robot 0 was not slowed down
    (rec,) = [r for r in records if r["type"] == "reschedule"]
    assert rec["switches"] == [[[2, 1], 1, 0]]
    assert check_trace(records).ok


def test_the_estimate_holds_a_robot_waiting_for_a_blocked_cell() -> None:
    adg = ADG(CROSSING)
    mon = Monitor(adg, now_ms=0.0)
    held = mon.with_holds({0: 5000.0})
    assert held.completion_ms(0, 0) == 6000.0 and held.robot_completion_ms(0) == 9000.0
    assert mon.completion_ms(0, 0) == 1000.0  # the original is left alone
    assert held.rewired(adg).completion_ms(0, 3) == 9000.0  # copies keep the hold


def test_the_registry_builds_the_reschedule_policies() -> None:
    assert make_policy("reschedule").name == "reschedule"
    combined = make_policy("reschedule+slack", threshold_ms=2000)
    assert combined.name == "reschedule+slack"
