"""Hand-computed estimates and slack (δ, Δ, Δ0, Δ̄, Δ̄F) on the paper's small cases.

All actions take t_x = 1000 ms and robots are released at 0. Notation: A0 = a_0^A, etc.
"""

from __future__ import annotations

from gateway.execution.commands import Completed, Dispatch, SolveRequest, Trigger
from gateway.execution.oneshot.executor import Executor
from gateway.execution.oneshot.policies import SlackReplan
from gateway.planning.plan import Plan
from tests.execution.support import is_one_robust
from tests.execution.test_adg import CORRIDOR, CROSSING

A, B = 0, 1
RED, BLUE = 0, 1


def test_fixtures_are_one_robust() -> None:
    assert is_one_robust(CROSSING) and is_one_robust(CORRIDOR)


def test_crossing_with_planned_wait_waits_kept() -> None:
    # Edges: A0->A1, B0->B1->B2->B3 (Type 1), A1->B2 (Type 2).
    # Initial estimate: A0 [0,1000] A1 [1000,2000]; B0 [0,1000] B1 [1000,2000];
    # B2 starts at max(tc(B1), tc(A1)) = 2000, ends 3000; B3 [3000,4000].
    # δ(A1->B2) = tc(A1) - tc(B1) = 2000 - 2000 = 0: with the waits kept as actions the planned
    # wait is inside B0/B1, so Δ0(B2) = 0 (see the drop_waits variant for Δ0 > 0).
    ex = Executor(Plan.of(CROSSING))
    ex.start(0)
    m = ex.monitor
    assert [m.completion_ms(A, i) for i in range(2)] == [1000, 2000]
    assert [m.completion_ms(B, i) for i in range(4)] == [1000, 2000, 3000, 4000]
    assert m.initial_slack(B, 2) == 0 and m.fleet_slack() == 0
    assert m.estimated_soc_ms() == 6000 and m.estimated_makespan_ms() == 4000
    ex.started(A, 0, 0, 0)
    ex.started(B, 0, 0, 0)
    ex.finished(B, 0, 0, 1000)
    ex.started(B, 0, 1, 1000)
    # t = 1500, A0 (started at 0) is late: clamped tc(A0) = max(0 + 1000, 1500) = 1500,
    # A1 [1500, 2500]; B1 (started 1000) tc = max(2000, 1500) = 2000;
    # B2 starts max(2000, 2500) = 2500 -> δ = 2500 - 2000 = 500 = Δ(B2) = Δ̄(B2) = Δ̄F.
    ex.tick(1500)
    assert m.completion_ms(A, 0) == 1500 and m.start_ms(A, 1) == 1500
    assert m.completion_ms(B, 1) == 2000
    assert m.start_ms(B, 2) == 2500 and m.action_slack(B, 2) == 500
    assert m.slack_growth(B, 2) == 500 and m.fleet_slack() == 500
    assert m.estimated_soc_ms() == 2500 + 4500 and m.estimated_makespan_ms() == 4500
    ex.finished(B, 0, 1, 2000)  # B1 on time (real tc = 2000)
    # t = 2500: A0 finishes 1500 ms late. A1 ready: ts = max(2500, now) = 2500, tc 3500.
    # B2: ts = max(tc(B1)=2000, tc(A1)=3500) = 3500; δ = 3500 - 2000 = 1500.
    ex.finished(A, 0, 0, 2500)
    assert [c for c in ex.drain() if isinstance(c, Dispatch)][-1].robot == A
    assert m.start_ms(A, 1) == 2500 and m.completion_ms(A, 1) == 3500
    assert m.action_slack(B, 2) == 1500 and m.slack_growth(B, 2) == 1500
    assert m.fleet_slack() == 1500
    assert m.robot_slack(B) == 1500 and m.robot_slack(A) == 0  # A1 has no Type 2 in-edge
    assert m.blocking_edges() == [(B, 2, A, 1)]  # B waits for A's a_1
    ex.started(A, 0, 1, 2500)
    ex.finished(A, 0, 1, 3500)
    assert m.blocking_edges() == []
    # B2 is now ready but not started: its Δ is historic, tc(A1) real 3500 - tc(B1) 2000.
    assert m.fleet_slack() == 1500
    ex.started(B, 0, 2, 3500)
    assert m.fleet_slack() == 0  # only B3 (no Type 2 in-edge) is left unstarted
    ex.finished(B, 0, 2, 4500)
    ex.started(B, 0, 3, 4500)
    ex.finished(B, 0, 3, 5500)
    # SOC = completion of A's last action 3500 + B's 5500; makespan 5500.
    assert ex.done and ex.soc_ms == 9000 and ex.makespan_ms == 5500
    assert ex.drain()[-1] == Completed(9000, 5500)


def test_crossing_with_planned_wait_drop_waits() -> None:
    # Without wait vertices B's first action is B2 and its δ uses B's release time (0):
    # initially tc(A1) = 2000 -> Δ0(B2) = 2000 - 0 = 2000, Δ̄(B2) = 0, Δ̄F = 0.
    ex = Executor(Plan.of(CROSSING), drop_waits=True)
    ex.start(0)
    m = ex.monitor
    assert [d.robot for d in ex.drain() if isinstance(d, Dispatch)] == [A]  # B2 not ready
    assert m.start_ms(B, 2) == 2000 and m.initial_slack(B, 2) == 2000
    assert m.action_slack(B, 2) == 2000 and m.slack_growth(B, 2) == 0 and m.fleet_slack() == 0
    ex.started(A, 0, 0, 0)
    # A0 finishes at 2500 (1500 ms late): A1 [2500, 3500], Δ(B2) = 3500 - 0 = 3500,
    # Δ̄(B2) = 3500 - 2000 = 1500: the same growth as with the waits kept.
    ex.finished(A, 0, 0, 2500)
    assert m.action_slack(B, 2) == 3500 and m.slack_growth(B, 2) == 1500
    assert m.fleet_slack() == 1500 and m.robot_slack(B) == 1500


def _corridor_until_red_finishes(ex: Executor) -> None:
    ex.start(0)
    ex.started(RED, 0, 0, 0)
    ex.started(BLUE, 0, 0, 0)
    ex.finished(BLUE, 0, 0, 1000)  # blue's planned wait; b1 needs r0 (not done)


def test_corridor_fig4_delay_of_the_leader() -> None:
    # Edges r0->b1, r1->b2, r2->b3. Initially r_i [1000 i, 1000(i+1)], b0 [0,1000],
    # b1 [1000,2000], b2 [2000,3000], b3 [3000,4000]; every δ = 0, so Δ0 = 0 everywhere.
    # Red's r0 is delayed by X = 2500 ms (finishes at 3500 instead of 1000).
    # While red is late, at time t in (1000, 3500]: tc(r0) = t (clamped), tc(b0) = 1000 (real)
    # -> δ(r0->b1) = t - 1000; downstream tc(r1) = t + 1000 = tc(b1) -> δ(r1->b2) = 0, and
    # likewise δ(r2->b3) = 0. So Δ̄F = t - 1000 exactly.
    ex = Executor(Plan.of(CORRIDOR))
    _corridor_until_red_finishes(ex)
    m = ex.monitor
    assert m.fleet_slack() == 0 and all(m.initial_slack(BLUE, i) == 0 for i in range(4))
    for t in range(1100, 3600, 100):
        ex.tick(t)
        assert m.fleet_slack() == t - 1000
        assert m.action_slack(BLUE, 1) == t - 1000
        assert m.action_slack(BLUE, 2) == 0 and m.action_slack(BLUE, 3) == 0
    ex.finished(RED, 0, 0, 3500)
    # r0 real 3500: b1 and r1 ready at 3500 -> [3500,4500]; δ(r0->b1) = 3500 - 1000 = X.
    assert m.slack_growth(BLUE, 1) == 2500 and m.fleet_slack() == 2500
    assert m.estimated_makespan_ms() == 6500 and m.estimated_soc_ms() == 13000
    ex.started(RED, 0, 1, 3500)
    ex.started(BLUE, 0, 1, 3500)
    assert m.fleet_slack() == 0  # the waiting is over; nobody else is affected


def test_corridor_slack_policy_triggers_at_first_tick_above_threshold() -> None:
    # Δ̄F = t - 1000 > 2000 first at the 100 ms tick t = 3100 (Δ̄F = 2100).
    # Red's r0 is running (not blocked): it is not cancelled; blue is idle. When r0 finishes at
    # 3500 every robot is idle: SolveRequest from red at (2,0), blue at (0,0), same goals.
    ex = Executor(Plan.of(CORRIDOR), policy=SlackReplan(2000))
    _corridor_until_red_finishes(ex)
    ex.drain()
    for t in range(1100, 3100, 100):
        ex.tick(t)
        assert ex.drain() == []
    ex.tick(3100)
    assert ex.drain() == [Trigger("slack", 2100)]
    ex.finished(RED, 0, 0, 3500)
    assert ex.drain() == [SolveRequest(((2, 0), (0, 0)), ((5, 0), (3, 0)))]
    new = Plan.of([[(2, 0), (3, 0), (4, 0), (5, 0)], [(0, 0), (1, 0), (2, 0), (3, 0)]])
    ex.adopt_plan(new, 3500)
    assert ex.plan_id == 1
    m = ex.monitor
    # released at 3500: r0' [3500,4500], b0' [3500,4500], b1' after r0' -> [4500,5500]: δ = 0
    assert m.start_ms(RED, 0) == 3500 and m.start_ms(BLUE, 1) == 4500
    assert m.initial_slack(BLUE, 1) == 0 and m.fleet_slack() == 0
    assert m.estimated_soc_ms() == 6500 + 6500


def test_long_delay_keeps_slack_exact_through_heap_compaction() -> None:
    # Same corridor, red's r0 stuck for 30 s: every tick raises Δ(b1) (one heap push each),
    # far more pushes than the 2 V + 64 entries that trigger a compaction of the lazy heaps.
    ex = Executor(Plan.of(CORRIDOR))
    _corridor_until_red_finishes(ex)
    m = ex.monitor
    for t in range(1100, 31_000, 100):
        ex.tick(t)
        assert m.fleet_slack() == m.robot_slack(BLUE) == t - 1000
        assert m.robot_slack(RED) == 0
