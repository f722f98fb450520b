"""The turning motion model in the execution core: turns are ADG vertices with Type 1 edges
only, t_x per action kind and robot model, and Algorithm 1 stays exact (numbers derived by hand
below; random runs checked against the full recomputation by support.Driver)."""

from __future__ import annotations

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from gateway.execution.actions import ActionDurations, action_kind
from gateway.execution.commands import Dispatch, PlanAdopted, SolveRequest
from gateway.execution.errors import ExecutionError
from gateway.execution.oneshot.adg import ADG
from gateway.execution.oneshot.executor import Executor
from gateway.planning.plan import Plan
from tests.execution.support import (
    Driver,
    brute_type2,
    random_robust_plan,
    turning_expand,
    turning_plan,
)

# A stands on (0,0) facing north (3): it turns clockwise to east (0), then drives to (2,0).
# B stands on (1,1) facing east: it turns counter-clockwise to north, waits twice, then drives
# north into (1,0) once A has left it (1-robust: A is on (1,0) at t=2, B enters at t=4).
A_CELLS = [(0, 0), (0, 0), (1, 0), (2, 0)]
A_HEADS = [3, 0, 0, 0]
B_CELLS = [(1, 1), (1, 1), (1, 1), (1, 1), (1, 0)]
B_HEADS = [0, 3, 3, 3, 3]
SLOW_TURNS = ActionDurations(move_ms=1000.0, turn_ms=1500.0, wait_ms=500.0)


def _turning() -> Plan:
    return turning_plan([A_CELLS, B_CELLS], [A_HEADS, B_HEADS])


def test_action_kinds_follow_the_turning_rules() -> None:
    assert action_kind((0, 0), (0, 0), 3, 0) == "turn"  # clockwise
    assert action_kind((0, 0), (0, 0), 0, 3) == "turn"  # counter-clockwise
    assert action_kind((0, 0), (0, 0), 2, 2) == "wait"
    assert action_kind((2, 2), (2, 1), 3, 3) == "move"  # north is -y
    assert action_kind((2, 2), (3, 2), None, None) == "move"  # omni
    for args, message in [(((0, 0), (0, 0), 0, 2), "a turn is 90 degrees"),
                          (((0, 0), (1, 0), 1, 1), "not one cell forward"),
                          (((1, 0), (0, 0), 0, 0), "not one cell forward"),  # backwards
                          (((0, 0), (1, 0), 1, 0), "changes the heading"),
                          (((0, 0), (0, 0), 0, 4), "heading must be 0..3"),
                          (((0, 0), (2, 0), None, None), "jumps from")]:
        with pytest.raises(ExecutionError, match=message):
            action_kind(*args)  # type: ignore[arg-type]


def test_turns_are_vertices_without_type2_edges() -> None:
    plan = _turning()
    adg = ADG(plan)
    assert adg.n_vertices == 3 + 4
    assert [adg.kind[adg.vertex(0, i)] for i in range(3)] == ["turn", "move", "move"]
    assert [adg.kind[adg.vertex(1, i)] for i in range(4)] == ["turn", "wait", "wait", "move"]
    # A's a_2 leaves (1,0), B's a_3 enters it; the turns hold (0,0) and (1,1): no other edge
    assert list(adg.type2_edges()) == [(0, 2, 1, 3)]
    assert adg.predecessors(adg.vertex(0, 0)) == []
    assert adg.predecessors(adg.vertex(1, 1)) == [adg.vertex(1, 0)]  # Type 1 only
    # a turn is never dropped as a wait
    dropped = ADG(plan, drop_waits=True)
    assert dropped.n_vertices == 3 + 2
    assert dropped.kind[dropped.vertex(1, 0)] == "turn"
    with pytest.raises(ExecutionError, match="is a wait"):
        dropped.vertex(1, 1)


@pytest.mark.parametrize(("heads", "message"), [
    ([[2, 1, 1, 1], B_HEADS], "robot 0 action 1: move from .* not one cell forward"),
    ([[1, 3, 3, 3], B_HEADS], "robot 0 action 0: turn from heading 1 to 3"),
])
def test_adg_refuses_illegal_turning_plans(heads: list[list[int]], message: str) -> None:
    with pytest.raises(ExecutionError, match=message):
        ADG(turning_plan([A_CELLS, B_CELLS], heads))


def test_dispatches_carry_headings_and_per_kind_durations() -> None:
    plan = _turning()
    ex = Executor(plan, durations=SLOW_TURNS)
    ex.start(0.0)
    cmds = ex.drain()
    assert cmds[0] == PlanAdopted(0, plan)
    assert cmds[1:] == [Dispatch(0, 0, 0, (0, 0), (0, 0), 1500.0, 3, 0),
                        Dispatch(0, 1, 0, (1, 1), (1, 1), 1500.0, 0, 3)]
    assert [c.kind for c in cmds[1:] if isinstance(c, Dispatch)] == ["turn", "turn"]


def test_estimates_and_slack_with_turns_by_hand() -> None:
    ex = Executor(_turning(), durations=SLOW_TURNS)
    ex.start(0.0)
    ex.drain()
    mon = ex.monitor
    # Initial estimate (turn 1500, move 1000, wait 500), release 0:
    #   A: a0 turn 0-1500, a1 move 1500-2500, a2 move 2500-3500
    #   B: a0 turn 0-1500, a1 wait 1500-2000, a2 wait 2000-2500,
    #      a3 move starts at max(t_c(B a2)=2500, t_c(A a2)=3500) = 3500, ends 4500
    #   Δ(B a3) = t_c(A a2) - t_c(B a2) = 1000 = Δ0
    assert [mon.completion_ms(0, i) for i in range(3)] == [1500, 2500, 3500]
    assert [mon.completion_ms(1, i) for i in range(4)] == [1500, 2000, 2500, 4500]
    assert mon.action_slack(1, 3) == mon.initial_slack(1, 3) == 1000
    assert mon.fleet_slack() == 0
    # B runs on time; A's turn takes 2500 ms (finished at 2500 instead of 1500).
    ex.started(0, 0, 0, 0.0)
    ex.started(1, 0, 0, 0.0)
    ex.finished(1, 0, 0, 1500.0)
    ex.started(1, 0, 1, 1500.0)
    ex.finished(1, 0, 1, 2000.0)
    ex.started(1, 0, 2, 2000.0)
    ex.tick(2500.0)
    ex.finished(1, 0, 2, 2500.0)
    ex.finished(0, 0, 0, 2500.0)
    ex.started(0, 0, 1, 2500.0)
    # Now A: a1 2500-3500, a2 3500-4500; B a3: 4500-5500; Δ(B a3) = 4500 - 2500 = 2000,
    # Δ̄ = 2000 - 1000 = 1000 for the only Type 2 head not started.
    assert [mon.completion_ms(0, i) for i in range(3)] == [2500, 3500, 4500]
    assert mon.completion_ms(1, 3) == 5500
    assert mon.action_slack(1, 3) == 2000
    assert mon.fleet_slack() == mon.robot_slack(1) == 1000
    assert mon.estimated_soc_ms() == 4500 + 5500
    assert ex.robot_heading(0) == 0 and ex.robot_heading(1) == 3


def test_per_robot_models_and_replan_keeps_headings() -> None:
    fast = ActionDurations(move_ms=800.0, turn_ms=400.0, wait_ms=1000.0)
    ex = Executor(_turning(), durations=[SLOW_TURNS, fast])
    ex.start(0.0)
    dispatches = [c for c in ex.drain() if isinstance(c, Dispatch)]
    assert [d.duration_ms for d in dispatches] == [1500.0, 400.0]
    # B (fast model): turn 400, waits 1000 each -> 2400; a3 after A's a2 (3500): 3500-4300
    assert ex.monitor.completion_ms(1, 3) == 4300
    ex.started(0, 0, 0, 0.0)
    ex.started(1, 0, 0, 0.0)
    ex.finished(1, 0, 0, 400.0)
    ex.request_replan(400.0)  # cancels B's wait a_1, dispatched at 400
    ex.cancelled(1, 0, 1, 400.0)
    ex.finished(0, 0, 0, 1500.0)
    cmds = ex.drain()
    (request,) = [c for c in cmds if isinstance(c, SolveRequest)]
    assert request == SolveRequest(((0, 0), (1, 1)), ((2, 0), (1, 0)), (0, 3))
    with pytest.raises(ExecutionError, match="robot 1: the new path starts with heading 0"):
        ex.adopt_plan(turning_plan([A_CELLS[1:], [(1, 1), (1, 0)]], [A_HEADS[1:], [0, 0]]),
                      1500.0)
    with pytest.raises(ExecutionError, match="must have headings exactly when"):
        ex.adopt_plan(Plan.of([A_CELLS[1:], [(1, 1), (1, 0)]]), 1500.0)
    ex.adopt_plan(turning_plan([A_CELLS[1:], [(1, 1), (1, 1), (1, 0)]],
                               [A_HEADS[1:], [3, 3, 3]]), 1500.0)
    assert ex.plan_id == 1


def test_type2_edges_of_turning_plans_match_brute_force() -> None:
    for seed in range(20):
        omni = random_robust_plan(seed, 4, 4, 4, 6)
        cells, heads = turning_expand(omni, seed)
        adg = ADG(Plan(tuple(tuple(p) for p in cells), tuple(tuple(h) for h in heads)))
        assert sorted(adg.type2_edges()) == brute_type2(cells)
        for v in range(adg.n_vertices):
            if adg.kind[v] == "turn":
                assert not adg.t2_pred[adg.t2_pred_ptr[v]:adg.t2_pred_ptr[v + 1]]
                assert not adg.t2_succ[adg.t2_succ_ptr[v]:adg.t2_succ_ptr[v + 1]]


@st.composite
def turning_plans(draw: st.DrawFn) -> Plan:
    """A random 1-robust omni plan made a turning plan (support.turning_expand)."""
    width, height = draw(st.integers(3, 5)), draw(st.integers(2, 4))
    robots = draw(st.integers(1, min(5, width * height // 2)))
    omni = random_robust_plan(draw(st.integers(0, 10**6)), width, height, robots,
                              draw(st.integers(1, 6)))
    return turning_plan(*turning_expand(omni, draw(st.integers(0, 10**6))))


@settings(max_examples=60, deadline=None)
@given(plan=turning_plans(), seed=st.integers(0, 10**6), drop_waits=st.booleans(),
       replan_at=st.integers(0, 8000),
       turn_ms=st.sampled_from([300.0, 1000.0, 2500.0]))
def test_turning_runs_keep_algorithm1_exact(plan: Plan, seed: int, drop_waits: bool,
                                            replan_at: int, turn_ms: float) -> None:
    models = [ActionDurations(1000.0, turn_ms, 700.0), ActionDurations()]
    durations = [models[k % 2] for k in range(len(plan.paths))]
    ex = Executor(plan, durations=durations, drop_waits=drop_waits)
    driver = Driver(ex, seed, replan_at_ms=replan_at, abandon_prob=0.3)
    driver.run()  # checks the monitor against Algorithm 1 after every event
    assert ex.done
    final = driver.plans[-1]
    assert final.headings is not None
    assert set(final.finished) == {(k, i) for k, p in enumerate(final.paths)
                                   for i in range(len(p) - 1)
                                   if not (drop_waits and p[i] == p[i + 1]
                                           and final.headings[k][i] == final.headings[k][i + 1])}
