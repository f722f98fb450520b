"""A lifelong shift of simulated VDA 5050 vehicles survives SIGKILL of the gateway: ``fleetgate
serve`` (its own process, a ``[vda5050]`` section, a private mosquitto) is killed twice
mid-shift and restarted with the same command line; the vehicles keep their orders meanwhile,
the restarted master takes them over from their states, and the same shift goes on: no action
driven twice, no pick or drop run twice, nothing a vehicle drove before a kill missing from the
trace, tracecheck clean (``bench.crash.lifelong_shift``, the crash benchmark's shift)."""

from __future__ import annotations

import asyncio
import random
from pathlib import Path

from bench.crash import GatewayProcess, Progress, free_port, lifelong_config, lifelong_shift
from gateway.planning.lorr import warehouse_problem
from gateway.server.config import GatewayConfig, LifelongSettings
from sim_clients.vda_fleet import shift_starts, vda_config

ROBOTS, WAREHOUSE = 6, (2, 3)


def test_a_killed_gateway_resynchronises_its_vehicles(broker_url: str, tmp_path: Path) -> None:
    vda = vda_config(broker_url, list(range(ROBOTS)), ("2.0.0", "2.1.0"))
    gw = GatewayProcess(tmp_path, free_port(), 5.0, "none",
                        extra={"vda5050": vda.model_dump(mode="json", exclude_none=True)})
    lifelong_config(gw, ROBOTS, WAREHOUSE)
    starts = shift_starts(GatewayConfig(map=None, lifelong=LifelongSettings(
        robots=ROBOTS, warehouse=WAREHOUSE)))
    rng = random.Random(3)
    grid = warehouse_problem(ROBOTS, 0, WAREHOUSE, p_delay=0.0).grid
    # killed on progress, not after a wall-clock delay (a loaded machine gets there later):
    # each kill once 30-60 more edges were driven since the start or the last restart (at a
    # random point of the vehicles' actions), then 30 more
    kills = [Progress(actions=rng.randint(30, 60)) for _ in range(2)]
    out = asyncio.run(lifelong_shift(gw, ROBOTS, 5.0, kills, Progress(actions=30), rng, grid,
                                     vda, starts, progress_timeout_s=120.0))
    assert out["stalled"] == 0  # after the start and each restart the shift got that far
    assert out["resumed"] == 2 and out["run_ids"] == 1
    for key in ("collisions", "trace_errors", "renumbered", "dispatched_twice", "duplicated",
                "lost", "errands_twice", "finished_twice", "robot_changed", "robot_errors"):
        assert out[key] == 0, (key, out)
    # the vehicles drove 90 edges or more (3 x 30 at least): the shift went on after the
    # kills; the trace has them (but the last few, finished while the fleet stopped)
    assert out["actions_run"] > 80
