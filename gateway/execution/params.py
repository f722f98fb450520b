"""The execution parameters and their defaults, the paper's (DESIGN section 2), in one place.

Every driver, configuration model and command takes its defaults from :data:`PAPER`: the
gateway's pydantic configuration, the simulator's and the campaign's dataclasses, the CLI
options. A plain frozen dataclass, because the execution core imports no pydantic.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

IntruderReading = Literal["start", "arrival"]
"""How the intruder reads "scheduled to visit the cell in T_a + 2 s" (see
``sim_clients.intruder.IntruderConfig.reading``)."""
INTRUDER_READINGS: tuple[IntruderReading, ...] = ("start", "arrival")


@dataclass(frozen=True, slots=True)
class ExecutionParams:
    """Timing of execution, monitoring, replanning and the simulated intruder (ms)."""

    action_ms: float = 1000.0
    """Expected duration ``t_x`` of every action (and the simulated robots' real one)."""
    threshold_ms: float = 2000.0
    """Fleet-slack threshold Δ̄T of the slack policy: replan when Δ̄F exceeds it."""
    monitor_period_ms: int = 100
    """Period of the executor's ticks (policy checks, clamping estimates to the present)."""
    max_replans: int = 1
    """Replans allowed per run (each experiment of the paper replans at most once)."""
    intruder_appear_ms: float = 3000.0
    """``T_a``: when the intruder appears (and the earliest random replan)."""
    intruder_leave_ms: float = 10000.0
    """``T_d``: when the intruder leaves."""
    intruder_lead_ms: float = 2000.0
    """The intruder takes the first cell its robot should enter at or after ``T_a`` + this."""
    random_margin_ms: float = 3000.0
    """A random replan happens before ``makespan_lb`` minus this margin."""
    recheck_ms: float = 100.0
    """How often a simulated robot (or the intruder) re-checks that its next cell is free."""
    shadow_margin_ms: float = 1000.0
    """Shadow planning adopts a plan only if it is estimated to save at least this much (sum
    of completion times)."""
    shadow_period_ms: float = 500.0
    """Shadow planning starts a background solve at most this often."""
    shadow_min_slack_ms: float = 1000.0
    """Shadow planning solves while the fleet slack or a reported block is at least this."""
    shadow_risk_aversion: float = 1.0
    """Shadow planning counts the expected regret of a plan (its mean loss against keeping
    the current one over the scenarios of the blocks' ends) this many times against its
    expected gain."""
    shadow_risk_level: float = 0.1
    """Shadow planning adopts no plan that loses at this quantile of the blocks' ends."""
    shadow_risk_confidence: float = 0.8
    """Shadow planning adopts a plan that may lose only if the chance of a loss is within
    ``shadow_risk_level`` with this confidence, given how many earlier blocks it rests on."""
    shadow_scenarios: int = 20
    """The equally likely scenarios of the blocks' ends shadow planning weighs."""
    oracle_step_ms: float = 250.0
    """The step of the oracle's sweep of forced replans (``fleetgate experiment --oracle``)."""


PAPER = ExecutionParams()
"""The paper's values: the default of every parameter above."""
