"""Turns in the simulator: a simulated robot turns in place (its cell only, 1 s by default,
configurable per kind), refuses a move it does not face, and whole turning runs with delays
and an intruder stay collision-free by the independent trace checker (exact SOC by hand)."""

from __future__ import annotations

import dataclasses
import random

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from gateway.execution.actions import ActionDurations
from gateway.execution.commands import Dispatch
from gateway.execution.trace_records import Record
from gateway.planning.instance import load_instance
from gateway.planning.random_plans import open_grid, random_plan
from gateway.planning.solver import solve
from gateway.runtime.deadline import WallDeadline
from gateway.runtime.mapstore import resolve
from sim_clients.des import SimConfig, run_simulation
from sim_clients.intruder import IntruderConfig, pick_target
from sim_clients.robot import RobotState, SimRobot, SimRobotError
from sim_clients.world import World
from tests.execution.support import turning_expand, turning_plan
from tracecheck import check_trace

# as in tests/execution/test_turning.py: A turns north -> east and drives to (2,0); B turns
# east -> north on (1,1), waits twice, and drives into (1,0) after A left it
PLAN = turning_plan([[(0, 0), (0, 0), (1, 0), (2, 0)],
                     [(1, 1), (1, 1), (1, 1), (1, 1), (1, 0)]],
                    [[3, 0, 0, 0], [0, 3, 3, 3, 3]])


def test_a_turn_holds_only_its_cell_and_changes_the_heading() -> None:
    w = World([(0, 0), (1, 0)])
    r = SimRobot(0, w, (0, 0), heading=3)
    turn = Dispatch(0, 0, 0, (0, 0), (0, 0), 1000.0, 3, 0)
    # a turn starts at once, even next to a robot, and enters no cell
    assert [(e.kind, e.t_ms) for e in r.dispatch(turn, 0.0)] == [("started", 0.0)]
    assert r.state is RobotState.MOVING and w.holders((0, 0)) == (0,) and w.is_free((0, 1))
    assert r.heading == 3  # still turning
    assert [e.kind for e in r.wake(1000.0)] == ["finished"]
    assert (r.cell, r.heading, w.collisions) == ((0, 0), 0, [])
    # a move must start facing the way the robot faces (here east)
    with pytest.raises(SimRobotError, match=r"robot 0 will face 0, but move 0\.0\.1 starts "
                                            "facing 1"):
        r.dispatch(Dispatch(0, 0, 1, (0, 0), (0, 1), 1000.0, 1, 1), 1000.0)
    # queued behind a turn, the next action starts from the turn's end heading
    r.dispatch(Dispatch(0, 0, 1, (0, 0), (0, 0), 1000.0, 0, 1), 1000.0)
    r.dispatch(Dispatch(0, 0, 2, (0, 0), (0, 1), 1000.0, 1, 1), 1000.0)
    assert [e.kind for e in r.wake(2000.0)] == ["finished", "started"]
    assert w.holders((0, 1)) == (0,) and r.heading == 1


@pytest.mark.parametrize(("durations", "soc", "makespan"), [
    # 1 s each: A ends at 3000; B's move waits for A's a_2 (ends 3000): 3000-4000
    (None, 7000.0, 4000.0),
    # turns 1500 ms: A 1500, 2500, 3500; B turn 1500, waits to 3500, move 3500-4500
    (ActionDurations(turn_ms=1500.0), 8000.0, 4500.0),
    # slow waits (2000 ms): A 1000, 2000, 3000; B turn 1000, waits 3000 and 5000, move to 6000
    (ActionDurations(wait_ms=2000.0), 9000.0, 6000.0),
])
def test_undelayed_turning_run_is_exact(durations: ActionDurations | None, soc: float,
                                        makespan: float) -> None:
    records: list[Record] = []
    result = run_simulation(SimConfig(open_grid(3, 2), PLAN, intruder=False, trace=records.append,
                                      durations=durations, solver_time="zero"))
    assert (result.soc_ms, result.makespan_ms, result.collisions) == (soc, makespan, 0)
    assert records[0]["motion"] == "turning"
    assert records[0]["agents"][1]["path"][:2] == [[1, 1, 0], [1, 1, 3]]
    report = check_trace(records)
    assert report.ok, report.errors
    assert (report.soc_ms, report.makespan_ms) == (soc, makespan)


def test_the_intruder_targets_a_cell_a_robot_enters_not_one_it_turns_on() -> None:
    # robot 0 turns twice on (0,0) (actions 0, 1), then enters (0,1) with action 2
    paths = (((0, 0), (0, 0), (0, 0), (0, 1)),)
    estimates = {0: 0.0, 1: 1000.0, 2: 2000.0}
    for lead in (0.0, 2000.0, 5000.0):
        assert pick_target(random.Random(0), paths, [0], lambda r, a: estimates[a],
                           lead) == (0, (0, 1))


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(w=st.integers(3, 5), h=st.integers(3, 5), seed=st.integers(0, 2**32 - 1),
       appear=st.integers(0, 4000), turn_ms=st.sampled_from([500.0, 1000.0, 1700.0]),
       delays=st.dictionaries(st.tuples(st.integers(0, 3), st.integers(0, 20)),
                              st.integers(1, 3000), max_size=6))
def test_turning_runs_with_delays_and_intruder_stay_safe(
        w: int, h: int, seed: int, appear: int, turn_ms: float,
        delays: dict[tuple[int, int], int]) -> None:
    rng = random.Random(seed)
    omni = random_plan(open_grid(w, h), rng.randint(1, min(4, w * h // 3)), 6, rng)
    plan = turning_plan(*turning_expand(omni.paths, seed))
    records: list[Record] = []
    config = SimConfig(open_grid(w, h), plan, seed=seed, intruder=True, trace=records.append,
                       durations=ActionDurations(turn_ms=turn_ms), solver_time="zero",
                       intruder_config=IntruderConfig(appear_ms=appear, leave_ms=appear + 4000),
                       extra_delay=lambda p, r, a: float(delays.get((r, a), 0)),
                       stall_ms=60_000.0)
    result = run_simulation(config)
    report = check_trace(records)
    assert report.ok, (report.errors, report.collisions)
    assert result.collisions == 0 and result.robot_blocks == 0
    assert report.soc_ms == result.soc_ms
    undelayed = run_simulation(dataclasses.replace(config, intruder=False, extra_delay=None,
                                                   trace=None))
    assert result.soc_ms >= undelayed.soc_ms


def test_a_turning_replan_solves_from_the_robots_poses() -> None:
    # lab, 6 robots, turning CBS; a low slack threshold makes the intruder trigger a replan:
    # the new plan starts from the cells and headings the robots hold (checked by the trace
    # checker), and the run stays collision-free
    inst = load_instance(resolve("lab", "map"), resolve("lab-random-1", "scen"), 6)
    plan = solve(inst.grid, inst.turning_starts(), inst.goals, motion="turning",
                 deadline=WallDeadline(30)).plan
    records: list[Record] = []
    result = run_simulation(SimConfig(inst.grid, plan, seed=0, policy="slack", threshold_ms=500,
                                      solver_time="zero", trace=records.append))
    assert result.replans == 1 and result.collisions == 0
    report = check_trace(records)
    assert report.ok, report.errors
    adopted = [r for r in records if r["type"] == "plan"]
    assert [r.get("motion") for r in adopted] == ["turning", "turning"]
