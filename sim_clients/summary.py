"""The run summary of ``fleetgate simulate --json`` and ``fleetgate demo --json`` (DESIGN
section 3), whichever driver ran the execution."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class RunSummary:
    """What every driver reports about one execution (times in ms of plan time)."""

    soc_ms: float
    makespan_ms: float
    plan_soc: int
    replans: int
    replan_at_ms: float | None
    """When the (first) replan was triggered; None if none was."""
    solver_ms: float
    """Solver time charged for replans."""
    collisions: int

    def summary(self) -> dict[str, object]:
        """``{"soc_ms", "makespan_ms", "plan_soc", "replans", "replan_at_ms", "solver_ms",
        "collisions"}``."""
        return {"soc_ms": self.soc_ms, "makespan_ms": self.makespan_ms,
                "plan_soc": self.plan_soc, "replans": self.replans,
                "replan_at_ms": self.replan_at_ms, "solver_ms": self.solver_ms,
                "collisions": self.collisions}
