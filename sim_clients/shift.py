"""A lifelong shift of simulated robots against a gateway in lifelong mode (over websockets
or in-memory links), for the demo, the load benchmark and the tests. The shift is driven as an
operator drives it: ``start`` (unless the gateway starts it itself) and ``stop_shift``."""

from __future__ import annotations

import asyncio
from dataclasses import dataclass

from gateway.server.gateway import Gateway
from protocol import Start, StopShift, parse_action_id
from sim_clients.fleet import SimFleet


@dataclass(frozen=True)
class ShiftStats:
    """What the network run did, from both ends: tasks, actions, lost and duplicated ids."""

    finished_tasks: int
    elapsed_ms: float
    dispatched: int
    lost: int
    """Actions the gateway dispatched that no robot received."""
    duplicated: int
    """Actions a robot was sent again (resends it dropped) or executed twice."""
    collisions: int
    """Robots that met on a cell in the simulated world."""


async def start_shift(gateway: Gateway, fleet: SimFleet, timeout_s: float = 60.0) -> None:
    """Connect every robot of ``fleet``; the gateway starts the shift once all are online
    (``autostart``), or now if autostart is off."""
    lifelong = gateway.engine.lifelong
    if lifelong is None:
        raise ValueError("the gateway is not in lifelong mode")
    await fleet.start()
    await fleet.wait_connected(timeout_s)
    if not gateway.config.autostart:  # the operator's start, as the GUI sends it
        error, detail = await gateway.command(Start(msg_id="shift-start", seq=0))
        if error is not None:
            raise ValueError(f"the shift did not start: {detail}")
    while lifelong.status == "loaded":
        await asyncio.sleep(0.01)


async def run_shift(gateway: Gateway, fleet: SimFleet, plan_ms: float) -> ShiftStats:
    """Start the shift (:func:`start_shift`), let it run until ``plan_ms`` of plan time, end
    it (:func:`stop_shift`) and stop the fleet; what the run did."""
    await start_shift(gateway, fleet)
    while gateway.engine.now_ms() < plan_ms:
        await asyncio.sleep(0.05)
    stats = await stop_shift(gateway, fleet)
    await fleet.stop()
    return stats


async def stop_shift(gateway: Gateway, fleet: SimFleet, timeout_s: float = 60.0
                     ) -> ShiftStats:
    """End the shift with the operator's ``stop_shift`` (robots finish what they were
    dispatched), then count, from both ends, what was dispatched, received, executed twice
    or lost."""
    lifelong = gateway.engine.lifelong
    assert lifelong is not None
    # refused only once the shift is ending or over (an operator stopped it, its task list ran
    # out): then it needs no stop, only the wait
    await gateway.command(StopShift(msg_id="shift-stop", seq=1))
    await asyncio.wait_for(gateway.wait_done(), timeout_s)
    ex = lifelong.executor
    # a robot's action numbers count up over the shift and it finishes them in order: every
    # number below its next index was dispatched (a session remembers only its latest
    # applied actions)
    sent = {(robot, index) for gs in gateway.engine.robots.values()
            for aid in (*gs.held, *gs.applied)
            for _, robot, index in [parse_action_id(aid)]}
    sent |= {(gs.robot_id, i) for gs in gateway.engine.robots.values()
             for i in range(gs.next_index)}
    got = {(robot, index) for aid in fleet.stats.received
           for _, robot, index in [parse_action_id(aid)]}
    return ShiftStats(finished_tasks=ex.finished_tasks, elapsed_ms=ex.now_ms,
                      dispatched=len(sent), lost=len(sent - got),
                      duplicated=fleet.stats.duplicates + len(fleet.stats.received) - len(got),
                      collisions=len(fleet.world.collisions))
