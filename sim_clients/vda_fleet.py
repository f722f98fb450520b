"""Many simulated VDA 5050 vehicles (:class:`sim_clients.vda_vehicle.VdaVehicle`) in one
process, each with its own MQTT connection (and so its own last will), on one shared world of
cells: a vehicle does not enter a cell another vehicle (or an obstacle) holds.

Real time: ``time.time()`` drives them; their speed is the vehicles' ``move_s``.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import time
from collections.abc import Iterable

import aiomqtt

from gateway.vda5050.broker import BrokerConfig, publish, will
from protocol.vda5050.master import Publish
from protocol.vda5050.topics import MASTER_PUBLISHES
from sim_clients.vda_vehicle import Cell, VdaVehicle

log = logging.getLogger("fleetgate.sim.vda5050")


class World:
    """Which cells the vehicles and obstacles hold: a vehicle holds its cell, and while it
    drives also the cell it drives into."""

    def __init__(self) -> None:
        self.vehicles: list[VdaVehicle] = []
        self.obstacles: set[Cell] = set()
        self.collisions = 0

    def add(self, vehicle: VdaVehicle) -> None:
        """Put ``vehicle`` into the world (it checks cells through it)."""
        self.vehicles.append(vehicle)
        vehicle.occupied = self.occupied

    def held(self, vehicle: VdaVehicle) -> set[Cell]:
        """The cells ``vehicle`` holds."""
        target = vehicle.target
        return {vehicle.cell} if target is None else {vehicle.cell, target}

    def occupied(self, cell: Cell, asking: VdaVehicle) -> bool:
        """Whether another vehicle or an obstacle holds ``cell``."""
        return cell in self.obstacles or any(
            cell in self.held(v) for v in self.vehicles if v is not asking)

    def count_collisions(self) -> int:
        """Count (and return the number of) pairs of vehicles on one cell now."""
        cells = [v.cell for v in self.vehicles]
        clashes = len(cells) - len(set(cells))
        self.collisions += clashes
        return clashes


async def run_vehicle(vehicle: VdaVehicle, broker: BrokerConfig, stop: asyncio.Event,
                      world: World | None = None) -> None:
    """Connect ``vehicle`` (last will CONNECTIONBROKEN, then ONLINE), follow its orders until
    ``stop`` is set, then go OFFLINE and disconnect gracefully."""
    topics = vehicle.topics
    broken, online = vehicle.connect(time.time())
    client = broker.client(f"{topics.manufacturer}-{topics.serial}",
                           will(topics.topic("connection"), broken.message))
    async with client:
        for name in MASTER_PUBLISHES:
            await client.subscribe(topics.topic(name), qos=0)
        await publish(client, topics.topic("connection"), "connection", online.message)
        messages = aiter(client.messages)
        stopping = asyncio.ensure_future(stop.wait())
        try:
            while not stop.is_set():
                now = time.time()
                vehicle.step(now)
                await _send(client, vehicle.drain(), vehicle)
                if world is not None:
                    world.count_collisions()
                wait = max(0.0, vehicle.next_wakeup_s() - time.time())
                nxt = asyncio.ensure_future(anext(messages))
                done, _ = await asyncio.wait({nxt, stopping}, timeout=wait,
                                             return_when=asyncio.FIRST_COMPLETED)
                if nxt not in done:
                    nxt.cancel()
                    with contextlib.suppress(asyncio.CancelledError, Exception):
                        await nxt
                    continue
                msg = nxt.result()
                payload = msg.payload if isinstance(msg.payload, bytes | str) else b""
                vehicle.receive(str(msg.topic).rsplit("/", 1)[-1], payload, time.time())
        finally:
            stopping.cancel()
        offline = vehicle.disconnect(time.time())
        await publish(client, topics.topic("connection"), "connection", offline.message)


async def _send(client: aiomqtt.Client, out: Iterable[Publish], vehicle: VdaVehicle) -> None:
    for item in out:
        await publish(client, vehicle.topics.topic(item.topic), item.topic, item.message)


async def run_fleet(vehicles: list[VdaVehicle], broker: BrokerConfig, stop: asyncio.Event,
                    world: World | None = None) -> None:
    """Run every vehicle until ``stop`` is set."""
    async with asyncio.TaskGroup() as group:
        for vehicle in vehicles:
            group.create_task(run_vehicle(vehicle, broker, stop, world))
