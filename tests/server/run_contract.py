"""The run contract (:class:`gateway.server.runs.base.Run`) as a suite any run must pass, through
a real gateway in virtual time with simulated robots on in-memory links: ``check_run(make)``.

``make()`` gives the configuration of a gateway whose run is loaded and not started
(``autostart`` off) and what to load into it (a one-shot plan; nothing for a shift). The
checks go through the operators' commands only: start, start again (refused), pause (nothing
starts any more: the count of applied finishes stops growing), resume (it grows again),
"replan now" (accepted), and what the run reports on the way (status, its core's pause)."""

from __future__ import annotations

import asyncio
from collections.abc import Callable
from dataclasses import dataclass

from gateway.server.clock import VirtualClock, run_virtual
from gateway.server.config import GatewayConfig
from gateway.server.gateway import Gateway
from gateway.server.planner import Problem
from protocol import ErrorCode, Pause, ReplanNow, Resume, Start
from sim_clients.fleet import SimFleet


@dataclass(frozen=True)
class RunSetup:
    """A gateway configuration (autostart off), its fleet's size and what to load (None: the
    run is loaded by the configuration)."""

    config: GatewayConfig
    robots: int
    problem: Problem | None = None


Make = Callable[[], RunSetup]


def _finished(gw: Gateway) -> float:
    """Action finishes the engine applied so far (its public metrics)."""
    value = gw.metrics.registry.get_sample_value("fleetgate_actions_finished_total")
    return 0.0 if value is None else value


async def _check(setup: RunSetup) -> None:
    async with Gateway(setup.config, clock=VirtualClock(solver_time=120.0)) as gw:
        if setup.problem is not None:
            gw.engine.load(setup.problem)
        fleet = SimFleet(gw.connect, range(setup.robots), clock=gw.clock, send_state=False)
        try:
            await fleet.start()
            await fleet.wait_connected(60)
            run = gw.engine.current_run
            assert gw.status == "loaded" and not run.ticking
            assert await gw.command(Start(msg_id="s1", seq=0)) == (None, "started")
            assert gw.status == "running" and run.ticking and run.core is not None
            code, _ = await gw.command(Start(msg_id="s2", seq=1))
            assert code is ErrorCode.BAD_STATE  # a run starts once
            await asyncio.sleep(4.0)
            assert _finished(gw) > 0
            assert await gw.command(Pause(msg_id="p", seq=2)) == (None, "paused")
            assert gw.status == "paused" and run.core.paused
            await asyncio.sleep(3.0)  # what was under way finishes
            frozen = _finished(gw)
            await asyncio.sleep(3.0)
            assert _finished(gw) == frozen  # nothing new started while paused
            assert await gw.command(Resume(msg_id="r", seq=3)) == (None, "resumed")
            assert gw.status in ("running", "replanning") and not run.core.paused
            await asyncio.sleep(4.0)
            assert _finished(gw) > frozen
            code, _ = await gw.command(ReplanNow(msg_id="n", seq=4))
            assert code is None
        finally:
            await fleet.stop()


def check_run(make: Make) -> None:
    """Run every check of the contract on a fresh gateway from ``make``."""
    run_virtual(_check(make()))
