"""A lifelong shift survives SIGKILL: ``fleetgate serve`` (its own process) runs a warehouse shift
of simulated robots over real websockets, is killed with SIGKILL twice mid-shift (robots
running actions, a planner call possibly outstanding) and restarted with the same command
line; the robots reconnect by themselves and the SAME shift goes on. The independent checker
(tracecheck) reads the one trace file the three processes appended to
(``bench.crash.lifelong_shift``, the crash benchmark's ``--lifelong`` shift, counts what went
wrong)."""

from __future__ import annotations

import asyncio
import random
from pathlib import Path

from bench.crash import GatewayProcess, free_port, lifelong_config, lifelong_shift
from gateway.planning.lorr import warehouse_problem

ROBOTS = 6


def test_a_killed_lifelong_gateway_continues_the_same_shift(tmp_path: Path) -> None:
    gw = GatewayProcess(tmp_path, free_port(), speed=10.0, policy="none")
    lifelong_config(gw, ROBOTS, (2, 3))
    rng = random.Random(7)
    grid = warehouse_problem(ROBOTS, 0, (2, 3), p_delay=0.0).grid
    out = asyncio.run(lifelong_shift(gw, ROBOTS, 10.0, [rng.uniform(1.5, 2.5) for _ in range(2)],
                                     3.0, rng, grid))
    assert out["resumed"] == 2  # both restarts went on with the shift
    assert out["run_ids"] == 1  # the robots saw one run: action ids went on
    # no collision, no other trace error, one shift start, plan time never went back,
    # no segment or action number repeated or skipped, nothing dispatched or executed twice,
    # every completion made before a kill in the trace, the batch's idempotency key kept,
    # task event ids without a gap, no task finished twice or moved once started
    for key in ("collisions", "trace_errors", "renumbered", "dispatched_twice", "duplicated",
                "lost", "retry_created", "event_gaps", "finished_twice", "robot_changed",
                "robot_errors"):
        assert out[key] == 0, (key, out)
    assert out["actions_run"] > 100
    assert out["tasks_finished"] > out["finished_at_last_kill"] > 0  # the shift went on
