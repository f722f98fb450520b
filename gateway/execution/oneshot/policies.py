"""When to replan (DESIGN section 2): never, at a random time, on slack, or on operator request;
and two policies that are not the paper's: ``informed`` (slack's trigger, a replan that keeps
robots off the cells the fleet reported blocked) and ``shadow`` (solves in the background and
adopts a plan only when the estimate says it pays: :mod:`gateway.execution.oneshot.shadow`); and
when
to reschedule first (switch Type 2 edges without stopping the fleet).

Every policy answers ``should_replan(now_ms, monitor)`` at the executor's ticks; a time-based
policy also says when it next wants a tick (``next_wakeup_ms``) so event-driven drivers need not
poll. A policy that also reschedules (:class:`Rescheduling`) is asked
``should_reschedule(now_ms, monitor)`` first at every tick. The executor enforces the replan
budget (``max_replans``); an operator's "replan now" is ``Executor.request_replan`` and works
whatever the policy.
"""

from __future__ import annotations

import math
import random
from collections.abc import Callable, Sequence
from statistics import NormalDist
from typing import TYPE_CHECKING, Literal, Protocol, get_args, runtime_checkable

from gateway.execution.params import PAPER

if TYPE_CHECKING:
    from gateway.execution.oneshot.monitor import Monitor

PolicyName = Literal["none", "random", "slack", "operator", "informed", "shadow", "reschedule",
                     "reschedule+slack"]
"""Every replanning policy's name (the wire protocol's ``PolicyName`` must equal it)."""


class ReplanPolicy(Protocol):
    """The interface the executor uses to decide a replan."""

    name: str
    informed: bool
    """A replan keeps robots off the cells the fleet reported blocked (SolveRequest.obstacles)."""
    shadow: bool
    """The executor solves in the background and adopts when it pays (ShadowPolicy)."""

    def should_replan(self, now_ms: float, monitor: Monitor) -> bool:
        """True if a replan should start now."""
        ...

    def next_wakeup_ms(self) -> float | None:
        """The earliest time at which :meth:`should_replan` may turn True, if time-based."""
        ...


class NoReplan:
    """Never replan: pure retiming."""

    name = "none"
    informed = False
    shadow = False

    def should_replan(self, now_ms: float, monitor: Monitor) -> bool:
        """Always False."""
        return False

    def next_wakeup_ms(self) -> float | None:
        """No wakeups."""
        return None


class OperatorOnly(NoReplan):
    """Replan only when the operator asks (``Executor.request_replan``)."""

    name = "operator"


class RandomReplan:
    """Replan once at a uniformly random integral time in ``[T_a, makespan_lb - margin]``.

    ``T_a`` is the intruder's appearance time; if the interval is empty the replan is at
    ``T_a`` (DESIGN section 2, experiment (iii)). The time is drawn from ``random.Random(seed)``
    when the policy is built, so it is reproducible.
    """

    name = "random"
    informed = False
    shadow = False

    def __init__(self, seed: int, *, intruder_appear_ms: float = PAPER.intruder_appear_ms,
                 makespan_lb_ms: float, margin_ms: float = PAPER.random_margin_ms) -> None:
        lo, hi = float(intruder_appear_ms), float(makespan_lb_ms) - float(margin_ms)
        rng = random.Random(seed)
        self.replan_at_ms: float = float(rng.randint(int(lo), int(hi))) if hi > lo else lo
        self._fired = False

    def should_replan(self, now_ms: float, monitor: Monitor) -> bool:
        """True once, at the first call at or after the drawn time."""
        if self._fired or now_ms < self.replan_at_ms:
            return False
        self._fired = True
        return True

    def next_wakeup_ms(self) -> float | None:
        """The drawn time until it has fired."""
        return None if self._fired else self.replan_at_ms


class SlackReplan:
    """Replan when the fleet slack exceeds a threshold: ``Δ̄F > Δ̄T``."""

    name = "slack"
    informed = False
    shadow = False

    def __init__(self, threshold_ms: float = PAPER.threshold_ms) -> None:
        self.threshold_ms = float(threshold_ms)

    def should_replan(self, now_ms: float, monitor: Monitor) -> bool:
        """True while Δ̄F is above the threshold."""
        return monitor.fleet_slack() > self.threshold_ms

    def next_wakeup_ms(self) -> float | None:
        """Slack is checked at the regular ticks only."""
        return None


class InformedReplan(SlackReplan):
    """Slack's trigger, but the replan keeps every robot off the cells the fleet reported
    blocked until each block's estimated end (:mod:`gateway.execution.oneshot.blocks`)."""

    name = "informed"
    informed = True


class ShadowPolicy(NoReplan):
    """Shadow planning (:mod:`gateway.execution.oneshot.shadow`): while the fleet is delayed,
    solve in the background, informed, from where the robots would stop; adopt the plan only if it
    pays under the uncertainty of the blocks' ends (:meth:`adopts`).

    The gain (sum of completion times saved, the stop included) is estimated in one scenario
    per level of :attr:`levels`: every open block ends at that quantile of its duration, the
    history's conditioned on how long the block has lasted (:meth:`gateway.execution.oneshot.
    blocks.BlockTracker.end_quantiles`)."""

    name = "shadow"
    informed = True
    shadow = True

    def __init__(self, margin_ms: float = PAPER.shadow_margin_ms,
                 period_ms: float = PAPER.shadow_period_ms,
                 min_slack_ms: float = PAPER.shadow_min_slack_ms,
                 risk_aversion: float = PAPER.shadow_risk_aversion,
                 risk_level: float = PAPER.shadow_risk_level,
                 scenarios: int = PAPER.shadow_scenarios,
                 risk_confidence: float = PAPER.shadow_risk_confidence) -> None:
        if not (risk_aversion >= 0 and 0 <= risk_level <= 1 and scenarios >= 1
                and 0.5 <= risk_confidence < 1):
            raise ValueError("need risk_aversion >= 0, 0 <= risk_level <= 1, scenarios >= 1, "
                             "0.5 <= risk_confidence < 1")
        self.margin_ms = float(margin_ms)
        self.period_ms = float(period_ms)
        self.min_slack_ms = float(min_slack_ms)
        self.risk_aversion = float(risk_aversion)
        self.risk_level = float(risk_level)
        self.scenarios = float(int(scenarios))  # (a journal's snapshot keeps floats)
        self.risk_confidence = float(risk_confidence)

    @property
    def levels(self) -> tuple[float, ...]:
        """The probability levels of the scenarios (equally likely)."""
        n = int(self.scenarios)
        return tuple((k + 0.5) / n for k in range(n))

    def adopts(self, gains: Sequence[float], evidence: float = math.inf) -> bool:
        """Adopt a plan whose gain in the equally likely scenarios is ``gains`` (ms) if its
        expected gain, less ``risk_aversion`` times its expected regret against keeping the
        plan (the mean loss where it loses), is at least the margin, and the chance that it
        loses (the block ending too early for it) is at most ``risk_level``. ``evidence`` is
        how many earlier blocks the scenarios rest on (those that lasted longer than the
        block has); a plan that loses in any scenario must keep the chance of a loss within
        ``risk_level`` with ``risk_confidence`` (:func:`loss_bound`): a short history cannot
        show that blocks rarely end soon."""
        if not gains:
            return False
        n = len(gains)
        mean = sum(gains) / n
        regret = sum(-g for g in gains if g < 0) / n
        losing = sum(1 for g in gains if g < 0) / n
        if mean - self.risk_aversion * regret < self.margin_ms:
            return False
        return losing == 0 or loss_bound(losing, evidence, self.risk_confidence) \
            <= self.risk_level


def loss_bound(share: float, samples: float, confidence: float) -> float:
    """The one-sided Wilson upper bound at ``confidence`` of a probability estimated as
    ``share`` from ``samples`` observations (1 with none; ``share`` itself with infinitely
    many)."""
    if samples == math.inf:
        return share
    if samples <= 0:
        return 1.0
    z = NormalDist().inv_cdf(confidence)
    z2n = z * z / samples
    spread = z * math.sqrt(share * (1 - share) / samples + z2n / (4 * samples))
    return min(1.0, (share + z2n / 2 + spread) / (1 + z2n))


@runtime_checkable
class Rescheduling(Protocol):
    """A policy that also asks for reschedule-first (``Executor.reschedule``)."""

    def should_reschedule(self, now_ms: float, monitor: Monitor) -> bool:
        """True if the executor should try switching Type 2 edges now."""
        ...


class RescheduleFirst(NoReplan):
    """Reschedule-first: while the fleet slack exceeds ``reschedule_ms``, try (at most every
    ``retry_ms``) to let others pass the delayed robots by switching Type 2 edges, adopted
    only when the estimate says the fleet finishes earlier (no stop, no replan budget); never
    replan."""

    name = "reschedule"

    def __init__(self, *, reschedule_ms: float = PAPER.action_ms,
                 retry_ms: float = PAPER.action_ms) -> None:
        self.reschedule_ms = float(reschedule_ms)
        self.retry_ms = float(retry_ms)
        self.next_try_ms: float | None = None
        """No try before this (None: none yet)."""

    def should_reschedule(self, now_ms: float, monitor: Monitor) -> bool:
        """True when the fleet slack exceeds ``reschedule_ms`` and the last try is
        ``retry_ms`` ago."""
        if (self.next_try_ms is not None and now_ms < self.next_try_ms) \
                or monitor.fleet_slack() <= self.reschedule_ms:
            return False
        self.next_try_ms = now_ms + self.retry_ms
        return True


class RescheduleThenSlack(RescheduleFirst):
    """Reschedule first, and replan as the slack policy does (``Δ̄F > Δ̄T``): a reschedule
    that lets others pass brings the slack back down, so the full replan comes only when
    reordering could not help."""

    name = "reschedule+slack"

    def __init__(self, threshold_ms: float = PAPER.threshold_ms, **kwargs: float) -> None:
        super().__init__(**kwargs)
        self.threshold_ms = float(threshold_ms)

    def should_replan(self, now_ms: float, monitor: Monitor) -> bool:
        """True while Δ̄F is above the threshold."""
        return monitor.fleet_slack() > self.threshold_ms


PolicyFactory = Callable[[int, float, float, float], ReplanPolicy]
"""``(seed, threshold_ms, makespan_lb_ms, intruder_appear_ms) -> policy``."""

POLICIES: dict[str, PolicyFactory] = {
    "none": lambda seed, threshold, lb, appear: NoReplan(),
    "random": lambda seed, threshold, lb, appear: RandomReplan(
        seed, intruder_appear_ms=appear, makespan_lb_ms=lb),
    "slack": lambda seed, threshold, lb, appear: SlackReplan(threshold),
    "operator": lambda seed, threshold, lb, appear: OperatorOnly(),
    "informed": lambda seed, threshold, lb, appear: InformedReplan(threshold),
    "shadow": lambda seed, threshold, lb, appear: ShadowPolicy(),
    "reschedule": lambda seed, threshold, lb, appear: RescheduleFirst(),
    "reschedule+slack": lambda seed, threshold, lb, appear: RescheduleThenSlack(threshold),
}
"""The policy registry: every policy by name."""

POLICY_NAMES: tuple[PolicyName, ...] = get_args(PolicyName)
AUTONOMOUS_POLICIES: tuple[PolicyName, ...] = tuple(p for p in POLICY_NAMES if p != "operator")
"""The policies that need no operator: the simulator's and the campaign's choices."""


def make_policy(name: str, *, seed: int = 0, threshold_ms: float = PAPER.threshold_ms,
                makespan_lb_ms: float = 0.0,
                intruder_appear_ms: float = PAPER.intruder_appear_ms) -> ReplanPolicy:
    """A policy by its name (one of :data:`POLICY_NAMES`)."""
    factory = POLICIES.get(name)
    if factory is None:
        raise ValueError(f"unknown replanning policy {name!r} ({', '.join(POLICY_NAMES)})")
    return factory(seed, threshold_ms, makespan_lb_ms, intruder_appear_ms)
