"""A block's duration as a distribution (the history conditioned on how long the block has
lasted, mixed with the scale-free prior) and shadow planning's risk-aware adoption rule:
hypothesis properties and small examples derived by hand."""

from __future__ import annotations

import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from gateway.execution.commands import SolveRequest
from gateway.execution.oneshot.adg import ADG
from gateway.execution.oneshot.blocks import BlockTracker, duration_quantiles
from gateway.execution.oneshot.executor import Executor
from gateway.execution.oneshot.policies import ShadowPolicy, loss_bound
from gateway.planning.plan import Plan

FAST = settings(max_examples=80, deadline=None)
HISTORY = st.lists(st.floats(1.0, 100_000.0), max_size=40)
LEVELS = tuple((k + 0.5) / 20 for k in range(20))


@FAST
@given(st.lists(st.integers(2001, 100_000).map(float), max_size=40, unique=True),
       st.floats(0.0, 60_000.0),
       st.floats(1.0, 2000.0))
def test_quantiles_lie_above_what_the_block_lasted(history: list[float], lasted: float,
                                                   min_ms: float) -> None:
    got = duration_quantiles(history, lasted, min_ms, LEVELS)
    assert got == sorted(got) and all(d >= max(lasted, min_ms) for d in got)
    # each gap between the earlier blocks that lasted longer holds 1 / (n + 1) of the mass:
    # the share of levels below the k-th longer block is k / (n + 1) (to the levels' grid)
    longer = sorted(d for d in history if d > lasted)
    n = len(longer)
    for k, d in enumerate(longer, start=1):
        if d > min_ms:
            below = sum(1 for v in got if v < d) / len(LEVELS)
            assert abs(below - k / (n + 1)) <= 1 / len(LEVELS) + 1e-9


@FAST
@given(HISTORY, st.floats(0.0, 30_000.0), st.floats(0.0, 30_000.0))
def test_lasting_longer_never_brings_the_end_forward(history: list[float], a: float,
                                                     b: float) -> None:
    """The duration given it lasted ``e2 > e1`` dominates the one given ``e1``: every
    quantile is at least as late."""
    e1, e2 = sorted((a, b))
    q1 = duration_quantiles(history, e1, 1000.0, LEVELS)
    q2 = duration_quantiles(history, e2, 1000.0, LEVELS)
    assert all(y >= x - 1e-6 for x, y in zip(q1, q2, strict=True))


@FAST
@given(st.lists(st.integers(1000, 60_000).map(float), min_size=200, max_size=300, unique=True),
       st.floats(0.0, 20_000.0))
def test_a_long_history_converges_to_its_conditional_quantiles(history: list[float],
                                                                lasted: float) -> None:
    longer = sorted(d for d in history if d > lasted)
    if len(longer) < 100:
        return
    got = duration_quantiles(history, lasted, 1000.0, [0.25, 0.5])
    for q, value in zip([0.25, 0.5], got, strict=True):
        rank = sum(1 for d in longer if d <= value) / len(longer)
        assert abs(rank - q) <= 2 / len(longer) + 0.01


def test_quantiles_by_hand() -> None:
    # History 3 s, 7 s and 20 s; the block lasted 4 s: the gaps (4, 7), (7, 20) and beyond
    # 20 s hold 1/3 each; beyond 20 s, P(D > x) = 20 / x of that third.
    got = duration_quantiles([3000.0, 7000.0, 20_000.0], 4000.0, 1000.0,
                             [1 / 6, 0.5, 0.9, 0.0])
    assert got == pytest.approx([5500.0, 13_500.0, 20_000.0 / 0.3, 4000.0])
    # no history: the scale-free prior alone, as likely to end before 2 e as after
    assert duration_quantiles([], 4000.0, 1000.0, [0.5, 0.75]) == pytest.approx(
        [8000.0, 16_000.0])
    # just opened, nothing known: a block lasts at least one action
    assert duration_quantiles([], 0.0, 1000.0, [0.5]) == [1000.0]


def test_tracker_end_quantiles_count_from_the_block_start() -> None:
    b = BlockTracker(min_ms=1000.0, history=[3000.0, 7000.0, 20_000.0])
    b.opened((1, 1), 10_000.0)
    b.still_blocked((1, 1), 14_000.0)
    assert b.end_quantiles((1, 1), [1 / 6, 0.5]) == pytest.approx([15_500.0, 23_500.0])


def test_adoption_by_hand() -> None:
    policy = ShadowPolicy(margin_ms=1000.0, risk_aversion=1.0, risk_level=0.0, scenarios=4)
    assert policy.levels == (0.125, 0.375, 0.625, 0.875)
    # Expected gain 2000, regret 250: 1750 >= 1000, but it loses if the block ends first.
    gains = [-1000.0, 3000.0, 3000.0, 3000.0]
    assert not policy.adopts(gains)
    lenient = ShadowPolicy(margin_ms=1000.0, risk_aversion=1.0, risk_level=0.25, scenarios=4)
    assert lenient.adopts(gains)
    # Regret counted 5 times: 2000 - 5 * 250 = 750 < 1000.
    averse = ShadowPolicy(margin_ms=1000.0, risk_aversion=5.0, risk_level=0.25, scenarios=4)
    assert not averse.adopts(gains)
    assert not policy.adopts([])
    # A plan that may lose needs the evidence: one loss in four scenarios, from four earlier
    # blocks, may well be one in two (the bound at 80% is 46%); one that never loses does not.
    assert not lenient.adopts(gains, evidence=4) and lenient.adopts(gains, evidence=math.inf)
    assert loss_bound(0.25, 4, 0.8) == pytest.approx(0.46, abs=0.01)
    assert lenient.adopts([1000.0, 3000.0, 3000.0, 3000.0], evidence=0)


def test_loss_bound_by_hand() -> None:
    # With no failure seen in n samples the bound is z^2 / (n + z^2), z = 0.8416 at 80%.
    z2 = 0.8416212 ** 2
    assert loss_bound(0.0, 1, 0.8) == pytest.approx(z2 / (1 + z2))
    assert loss_bound(0.0, 100, 0.8) == pytest.approx(z2 / (100 + z2))
    assert loss_bound(0.1, 0, 0.8) == 1.0 and loss_bound(0.1, math.inf, 0.8) == 0.1
    # more samples, a tighter bound; a larger share, a larger bound
    assert loss_bound(0.05, 10, 0.8) > loss_bound(0.05, 100, 0.8) > 0.05
    assert loss_bound(0.1, 100, 0.8) > loss_bound(0.05, 100, 0.8)


@FAST
@given(st.lists(st.floats(-50_000, 50_000), min_size=1, max_size=30),
       st.floats(0, 5), st.floats(0, 0.5), st.integers(0, 29), st.floats(0, 20_000))
def test_adoption_is_monotone_in_the_gains(gains: list[float], aversion: float, level: float,
                                           which: int, more: float) -> None:
    policy = ShadowPolicy(margin_ms=1000.0, risk_aversion=aversion, risk_level=level,
                          scenarios=len(gains))
    better = list(gains)
    better[which % len(gains)] += more
    assert not policy.adopts(gains) or policy.adopts(better)
    # a plan that gains the margin whatever the block does is adopted; one that never gains is
    # not
    assert policy.adopts([max(g, 1000.0) for g in gains])
    assert not policy.adopts([min(g, -1.0) for g in gains])


DETOUR = [(0, 0), (0, 1), (1, 1), (2, 1), (2, 0)]
"""Robot 0's way around the blocked (1,0): four moves instead of two."""


def _decide(history: list[float], policy: ShadowPolicy) -> tuple[bool, list[float]]:
    """Robot 0 (alone, (0,0) -> (2,0) along y = 0) finds (1,0) taken at 0 ms; at 1000 ms a
    shadow solve comes back with the detour. Was it adopted, and the gains of the
    scenarios."""
    ex = Executor(Plan.of([[(0, 0), (1, 0), (2, 0)]]), policy=policy,
                  block_history=history)
    ex.start(0.0)
    ex.drain()
    ex.blocked(0, 0, 0, 0.0)
    ex.tick(1000.0)
    (request,) = [c for c in ex.drain() if isinstance(c, SolveRequest)]
    assert request.shadow and request.starts == ((0, 0),) and request.start_ms == 1000.0
    gains = ex._shadow_gains(ADG(Plan.of([DETOUR])), 1000.0, policy.levels)
    return ex.shadow_solved(Plan.of([DETOUR]), 1000.0), gains


def test_adopting_a_detour_by_hand() -> None:
    """Keeping the plan, robot 0 finishes 2000 ms after the block ends (at E); the detour
    from 1000 ms finishes at 5000 ms: the gain is E - 3000 in every scenario."""
    policy = ShadowPolicy(margin_ms=1000.0, min_slack_ms=1000.0, risk_aversion=1.0,
                          risk_level=0.1)
    # Every earlier block lasted 10 s. Lasted 1 s: it ends in (1, 10) s with 1/20 (level
    # 0.025: 5.5 s), at 10 s (levels 0.075 .. 0.925), beyond with 1/20 (0.975: 20 s).
    adopted, gains = _decide([10_000.0] * 19, policy)
    assert gains == pytest.approx([2500.0] + [7000.0] * 18 + [17_000.0])
    assert adopted
    # Every earlier block lasted 2 s: the detour loses 1000 ms in 18 of 20 scenarios.
    adopted, gains = _decide([2000.0] * 19, policy)
    assert gains == pytest.approx([-1500.0] + [-1000.0] * 18 + [1000.0])
    assert not adopted
    # Three earlier blocks of 1.5 s, seventeen of 30 s: 21 gaps of 1/21. The detour gains
    # 27 s on average but loses if the block ends by 3 s: levels 0.025 (1262.5 ms), 0.075 and
    # 0.125 (1.5 s), 3 scenarios of 20 > the risk level 0.1.
    risky = [1500.0] * 3 + [30_000.0] * 17
    adopted, gains = _decide(risky, policy)
    assert gains[:4] == pytest.approx([-1737.5, -1500.0, -1500.0, 17_737.5])
    assert sum(gains) / 20 > 20_000 and not adopted
    bold = ShadowPolicy(margin_ms=1000.0, min_slack_ms=1000.0, risk_aversion=1.0,
                        risk_level=0.2)
    # 15% <= 0.2, but 20 earlier blocks cannot show it: the bound is 22.9% (Wilson, 80%)
    assert bold.adopts(gains) and not _decide(risky, bold)[0]
    assert loss_bound(0.15, 20, 0.8) == pytest.approx(0.229, abs=1e-3)
    assert _decide(risky, ShadowPolicy(margin_ms=1000.0, min_slack_ms=1000.0,
                                       risk_level=0.25))[0]
