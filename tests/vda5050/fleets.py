"""Run one planned instance through the real gateway with websocket-protocol robots (the
in-memory transport) or with simulated VDA 5050 vehicles through mosquitto, and return the
run's SOC and trace: the two transports are compared on the same plan."""

from __future__ import annotations

import asyncio
import json
import os
import time
from collections.abc import Awaitable, Callable
from dataclasses import dataclass, field
from pathlib import Path

from gateway.server.config import GatewayConfig
from gateway.server.gateway import Gateway
from gateway.vda5050.broker import BrokerConfig
from gateway.vda5050.config import Vda5050Config
from gateway.vda5050.transport import VdaTransport
from protocol.messages import LoadInstance, Start
from sim_clients.fleet import SimFleet
from sim_clients.vda_fleet import make_vehicles, run_fleet, vda_config
from sim_clients.vda_vehicle import VdaVehicle
from sim_clients.world import World

SPEED = 2.0
"""Plan time runs this much faster than real time (a 1 s action takes 0.5 s)."""


def config(trace: Path, vda: Vda5050Config | None = None) -> GatewayConfig:
    """A loopback gateway with a trace, at :data:`SPEED`."""
    return GatewayConfig(port=0, speed=SPEED, trace=trace, log_level="WARNING", vda5050=vda)


async def _load(gw: Gateway, map_name: str, scen: str, agents: int) -> None:
    code, detail = await gw.command(LoadInstance(msg_id="i", seq=0, map=map_name, scen=scen,
                                                 agents=agents))
    assert code is None, detail


async def run_websocket(trace: Path, map_name: str, scen: str, agents: int,
                        timeout_s: float = 120) -> float:
    """SOC (plan ms) of the instance run by simulated websocket-protocol robots."""
    async with Gateway(config(trace)) as gw:
        await _load(gw, map_name, scen, agents)
        fleet = SimFleet(gw.connect, range(agents), clock=gw.clock, send_state=False)
        await fleet.start()
        await fleet.wait_connected(30)
        await gw.command(Start(msg_id="s", seq=1))
        soc, _ = await asyncio.wait_for(gw.wait_done(), timeout_s)
        await fleet.stop()
        return soc


@dataclass
class VdaRun:
    """What a run with VDA 5050 vehicles left: SOC, the floor and every MQTT message."""

    soc_ms: float
    world: World
    vehicles: list[VdaVehicle]
    traffic: list[tuple[str, bytes]] = field(default_factory=list)


async def sniff(broker: BrokerConfig, seen: list[tuple[str, bytes]],
                ready: asyncio.Event) -> None:
    """Append every VDA 5050 message on the broker to ``seen`` (topic, payload); ``ready`` is
    set once subscribed."""
    async with broker.client("sniffer") as client:
        await client.subscribe("uagv/#", qos=1)
        ready.set()
        async for msg in client.messages:
            assert isinstance(msg.payload, bytes)
            seen.append((str(msg.topic), msg.payload))


async def run_vda(trace: Path, broker_url: str, map_name: str, scen: str, agents: int,
                  vda_robots: list[int], timeout_s: float = 120,
                  versions: tuple[str, ...] = ("2.1.0",),
                  during: Callable[[Gateway, World], Awaitable[None]] | None = None,
                  external: Path | None = None) -> VdaRun:
    """Run the instance with robots ``vda_robots`` as simulated VDA 5050 vehicles through the
    broker (the others: websocket-protocol robots in memory); ``during`` runs beside it once
    started. ``external``: a node_modules folder holding the npm package vda-5050-lib, whose
    virtual AGVs (an implementation fleetgate did not write) are the vehicles instead."""
    vda = vda_config(broker_url, vda_robots, versions)
    seen: list[tuple[str, bytes]] = []
    sniffing = asyncio.Event()
    sniffer = asyncio.create_task(sniff(vda.broker, seen, sniffing))
    await sniffing.wait()
    async with Gateway(config(trace, vda)) as gw:
        await _load(gw, map_name, scen, agents)
        problem = gw.engine.problem
        assert problem is not None and problem.plan is not None
        plan, starts = problem.plan, problem.instance.starts
        others = [r for r in range(agents) if r not in vda_robots]
        fleet = SimFleet(gw.connect, others, clock=gw.clock, send_state=False)
        world = fleet.world  # one floor for both kinds of robots
        vehicles = make_vehicles(vda, world, speed=SPEED, starts={
            r: (starts[r], plan.headings[r][0] if plan.headings is not None else None)
            for r in vda_robots})
        stop = asyncio.Event()
        if external is None:
            vehicles_task = asyncio.create_task(run_fleet(vehicles, vda.broker, stop))
        else:
            vehicles_task = asyncio.create_task(_external(external, vda, vehicles, stop))
            vehicles = []
        async with VdaTransport(gw, vda):
            if others:
                await fleet.start()
                await fleet.wait_connected(30)
            deadline = time.monotonic() + 30
            while not gw.engine.all_online(agents):
                assert time.monotonic() < deadline, "vehicles did not come online"
                await asyncio.sleep(0.05)
            await gw.command(Start(msg_id="s", seq=1))
            side = asyncio.create_task(during(gw, world)) if during else None
            soc, _ = await asyncio.wait_for(gw.wait_done(), timeout_s)
            if side is not None:
                await side
            if others:
                await fleet.stop()
        stop.set()
        await vehicles_task
    await asyncio.sleep(0.2)
    sniffer.cancel()
    return VdaRun(soc, world, vehicles, seen)


async def _external(modules: Path, vda: Vda5050Config, vehicles: list[VdaVehicle],
                    stop: asyncio.Event) -> None:
    """Run vda-5050-lib's virtual AGVs where ``vehicles`` stand, until ``stop``."""
    spec = {"interface": vda.interface_name, "vehicles": [
        {"manufacturer": v.topics.manufacturer, "serial": v.topics.serial,
         "mapId": vda.map_id, "theta": v.theta, "speed": SPEED * vda.cell_size_m,
         **dict(zip("xy", vda.nodes().position(v.cell, None).model_dump(
             include={"x", "y"}).values(), strict=True))}
        for v in vehicles]}
    script = Path(__file__).with_name("external_agvs.js")
    proc = await asyncio.create_subprocess_exec(
        "node", str(script), vda.broker.url, json.dumps(spec),
        env={**os.environ, "NODE_PATH": str(modules)}, stdout=asyncio.subprocess.PIPE)
    try:
        await stop.wait()
    finally:
        proc.terminate()
        await proc.wait()
