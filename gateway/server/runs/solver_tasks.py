"""The planner off the owner loop: one task per solve, its result back as a queue item.

The engine asks for a plan (a load, or a replan the executor requested); :class:`SolverTasks`
runs the planner as the clock decides (a thread in real time, charged virtual time under a
virtual clock), adds what a replan is charged to :attr:`SolverTasks.solver_ms`, and puts a
:class:`~gateway.server.items.SolverDone` on the owner's queue, which the engine handles like
any other item. Events keep queueing meanwhile.
"""

from __future__ import annotations

import asyncio
import time
from collections.abc import Sequence
from typing import Literal

from gateway.planning.grid import Cell
from gateway.planning.motion import Motion
from gateway.planning.plan import NoSolution, Plan
from gateway.planning.problem import Forbidden
from gateway.planning.solver import Place
from gateway.server.clock import Clock
from gateway.server.config import GatewayConfig
from gateway.server.items import Item, Reply, SolverDone
from gateway.server.planner import Problem, plan_for


class SolverTasks:
    """Running planner tasks, and the planner time charged to the current run's replans."""

    def __init__(self, config: GatewayConfig, clock: Clock, queue: asyncio.Queue[Item]) -> None:
        self._config = config
        self._clock = clock
        self._queue = queue
        self._tasks: set[asyncio.Task[None]] = set()
        self.solver_ms = 0.0
        """Planner time charged for replans of the current run (reset by the run's start)."""

    def spawn(self, purpose: Literal["load", "replan", "shadow"], problem: Problem,
              starts: Sequence[Place], goals: tuple[Cell, ...], reply: Reply,
              ref: str | None, motion: Motion, forbidden: Sequence[Forbidden] = ()) -> None:
        """Solve ``starts`` -> ``goals`` on ``problem``'s grid, off the ``forbidden`` cells,
        in a task; the plan (or the exception) comes back as a ``SolverDone`` item with
        ``reply`` and ``ref``. A shadow solve is not charged to the run (the fleet keeps
        moving meanwhile)."""
        grid, limit = problem.instance.grid, self._config.solver_time_limit_s
        fallback_s = self._config.fallback_s

        def work() -> Plan:
            return plan_for(grid, starts, goals, limit, fallback_s, motion, forbidden)

        async def run() -> None:
            t0 = time.perf_counter()
            try:
                result: Plan | Exception
                result, charged = await self._clock.run_solver(work)
                if purpose == "replan":
                    self.solver_ms += charged
            except (NoSolution, ValueError) as exc:
                result = exc
            wall = (time.perf_counter() - t0) * 1000.0
            self._queue.put_nowait(SolverDone(purpose, result, problem, reply, ref, wall))

        task = asyncio.get_running_loop().create_task(run(), name=f"solver-{purpose}")
        self._tasks.add(task)
        task.add_done_callback(self._tasks.discard)

    def cancel_all(self) -> None:
        """Cancel every running planner task (the gateway is closing)."""
        for task in list(self._tasks):
            task.cancel()
