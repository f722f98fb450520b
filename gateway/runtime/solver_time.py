"""What a planner call costs in virtual time (DESIGN section 2, ``--solver-time``).

Shared by the asyncio server's virtual clock and the discrete-event simulator.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Literal, TypeVar

T = TypeVar("T")

SolverTime = Literal["measured", "zero"] | float
"""How virtual time charges the planner: its CPU time, nothing, or a fixed number of ms."""


def run_charged(fn: Callable[[], T], solver_time: SolverTime) -> tuple[T, float]:
    """Run the planner call ``fn`` and say how many virtual ms it costs.

    "measured" charges the calling thread's CPU time rather than wall time: on an idle machine
    the two agree (the planner is single-threaded and does no I/O), but CPU time does not grow
    when other processes share the cores, so virtual-time results stay comparable across
    machines and loads (DESIGN says wall time; see the issue note for why we deviate).
    """
    t0 = time.thread_time()
    result = fn()
    return result, charge_ms((time.thread_time() - t0) * 1000.0, solver_time)


def charge_ms(cpu_ms: float, solver_time: SolverTime) -> float:
    """The virtual ms a planner call that took ``cpu_ms`` of CPU costs."""
    if solver_time == "measured":
        return cpu_ms
    return 0.0 if solver_time == "zero" else float(solver_time)
