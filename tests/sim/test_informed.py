"""Informed replanning in the simulator: the replan gets the blocks the robots reported, with
the tracker's own estimate of their end, never the intruder's real leave time."""

from __future__ import annotations

from typing import Any

import numpy as np

from gateway.execution.commands import SolveRequest
from gateway.planning.generators import random_instance
from gateway.planning.movingai import read_map
from gateway.planning.plan import Plan
from gateway.planning.solver import solve
from gateway.runtime.deadline import WallDeadline
from gateway.runtime.mapstore import resolve
from sim_clients.des import SimConfig, Simulation
from sim_clients.intruder import IntruderConfig


class _Recording(Simulation):
    """A simulation that keeps every solve request."""

    def __init__(self, config: SimConfig) -> None:
        super().__init__(config)
        self.requests: list[tuple[float, SolveRequest]] = []

    def plan_for(self, request: SolveRequest, now: float) -> tuple[Plan | None, float]:
        self.requests.append((now, request))
        return super().plan_for(request, now)


def test_the_replan_gets_the_reported_block_and_its_estimated_end() -> None:
    grid = read_map(resolve("lab", "map"))
    checked = 0
    for k in range(12):
        inst = random_instance(grid, 10, np.random.default_rng(k))
        plan = solve(grid, inst.starts, inst.goals, deadline=WallDeadline(20)).plan
        for informed in (False, True):
            records: list[dict[str, Any]] = []
            sim = _Recording(SimConfig(
                grid=grid, plan=plan, seed=k, policy="slack", solver_time="zero",
                informed=informed, trace=records.append,
                intruder_config=IntruderConfig(appear_ms=3000, leave_ms=10_000)))
            res = sim.run()
            assert res.collisions == 0 and res.robot_blocks == 0
            if not sim.requests:
                continue
            (now, req), = sim.requests
            if not informed:
                assert req.obstacles == ()
                continue
            on = [r for r in records if r["type"] == "intruder" and r["state"] == "on"]
            first = [r for r in records if r["type"] == "blocked"]
            assert on and first  # slack grew because the intruder blocked a robot
            cell = tuple(on[0]["cell"])
            since = first[0]["t_ms"]
            trigger, = (r["t_ms"] for r in records if r["type"] == "trigger")
            assert trigger <= now  # the solve waits for the running moves to end
            # The block reported, expected to last twice as long as it was seen (until the
            # replan cancelled the waiting robot; nothing earlier to go by), at least one
            # action: not the intruder's real 10 s.
            assert req.obstacles == ((cell, since + max(2 * (trigger - since), 1000.0)),)
            assert req.obstacles[0][1] != 10_000
            checked += 1
    assert checked >= 2
