"""Many simulated VDA 5050 vehicles (:class:`sim_clients.vda_vehicle.VdaVehicle`) in one
process, each with its own MQTT connection (and so its own last will); on a shared
:class:`sim_clients.world.World` a vehicle does not enter a cell another robot, vehicle or
obstacle holds.

Real time: ``time.time()`` drives them; their speed is the vehicles' ``move_s``.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import math
import random
import time
from collections.abc import Callable, Iterable, Mapping

import aiomqtt

from gateway.planning.grid import Cell
from gateway.server.config import GatewayConfig
from gateway.server.runs.lifelong import shift_from
from gateway.vda5050.broker import BrokerConfig, publish, will
from gateway.vda5050.config import Vda5050Config, VehicleConfig
from protocol.messages import HEADINGS
from protocol.vda5050.master import Publish, parse_order_id
from protocol.vda5050.nodes import THETA
from protocol.vda5050.topics import MASTER_PUBLISHES
from sim_clients.vda_vehicle import VdaVehicle
from sim_clients.world import World

log = logging.getLogger("fleetgate.sim.vda5050")


async def run_vehicle(vehicle: VdaVehicle, broker: BrokerConfig, stop: asyncio.Event) -> None:
    """Connect ``vehicle`` (last will CONNECTIONBROKEN, then ONLINE), follow its orders until
    ``stop`` is set, then go OFFLINE and disconnect gracefully.

    Driven by callbacks: a message, or the vehicle's next wake-up (one timer, moved as the
    wake-up moves), steps it and hands what it publishes to the client at once (no task or
    wait per step: hundreds of vehicles share the process with the benchmark's WMS)."""
    topics = vehicle.topics
    broken, online = vehicle.connect(time.time())
    loop = asyncio.get_running_loop()
    timer: asyncio.TimerHandle | None = None
    timer_at = math.inf

    def wake() -> None:
        nonlocal timer, timer_at
        now = time.time()
        vehicle.step(now)
        _send(client, vehicle.drain(), vehicle)
        at = vehicle.next_wakeup_s()
        if at != timer_at or timer is None:
            if timer is not None:
                timer.cancel()
            timer_at = at
            timer = loop.call_at(loop.time() + max(0.0, at - now), fire)

    def fire() -> None:
        nonlocal timer
        timer = None
        wake()

    def receive(msg: aiomqtt.Message) -> None:
        payload = msg.payload if isinstance(msg.payload, bytes | str) else b""
        vehicle.receive(msg.topic.value.rsplit("/", 1)[-1], payload, time.time())
        wake()

    async def read() -> None:
        async for _ in client.messages:  # ends with the connection (messages go to receive)
            pass

    client = broker.client(f"{topics.manufacturer}-{topics.serial}",
                           will(topics.topic("connection"), broken.message), receive)
    async with client:
        for name in MASTER_PUBLISHES:
            await client.subscribe(topics.topic(name), qos=0)
        publish(client, topics.topic("connection"), "connection", online.message)
        reader = loop.create_task(read())
        try:
            wake()
            await stop.wait()
        finally:
            if timer is not None:
                timer.cancel()
            reader.cancel()
            with contextlib.suppress(asyncio.CancelledError, aiomqtt.MqttError):
                await reader
        offline = vehicle.disconnect(time.time())
        publish(client, topics.topic("connection"), "connection", offline.message)


def _send(client: aiomqtt.Client, out: Iterable[Publish], vehicle: VdaVehicle) -> None:
    for item in out:
        publish(client, vehicle.topics.topic(item.topic), item.topic, item.message)


async def run_fleet(vehicles: list[VdaVehicle], broker: BrokerConfig,
                    stop: asyncio.Event) -> None:
    """Run every vehicle until ``stop`` is set."""
    async with asyncio.TaskGroup() as group:
        for vehicle in vehicles:
            group.create_task(run_vehicle(vehicle, broker, stop))


def vda_config(broker_url: str, robots: Iterable[int], versions: tuple[str, ...] = ("2.1.0",)
               ) -> Vda5050Config:
    """Vehicles ``fleetgate``/``sim<r>`` as robots ``r`` on the broker at ``broker_url``, their
    versions alternating over ``versions``."""
    return Vda5050Config(broker=BrokerConfig(url=broker_url), vehicles=[
        VehicleConfig(manufacturer="fleetgate", serial_number=f"sim{r}", robot_id=r,
                      version=versions[i % len(versions)])  # type: ignore[arg-type]
        for i, r in enumerate(robots)])


def make_vehicles(config: Vda5050Config, world: World | None, *, speed: float = 1.0,
                  starts: Mapping[int, tuple[Cell, int | None]] | None = None,
                  jitter: float = 0.0, seed: int = 0, action_s: float = 1.0
                  ) -> list[VdaVehicle]:
    """A simulated vehicle for every vehicle of ``config``: 1 s per move, 90-degree turn or
    wait divided by ``speed`` (times U(1 - ``jitter``, 1 + ``jitter``) per edge, seeded per
    vehicle), ``action_s`` per node action (pick, drop); robot ``r`` stands on ``starts[r]``
    (cell, plan heading) or, if not given, on the first node of its first order."""
    vehicles = []
    for v in config.vehicles:
        cell, heading = (starts or {}).get(v.robot_id, (None, None))
        theta = THETA[HEADINGS[heading]] if heading is not None else 0.0
        delay = None
        if jitter:
            rng = random.Random(seed * 1_000_003 + v.robot_id)
            delay = _jitter(rng, jitter / speed)
        vehicles.append(VdaVehicle(config.topics(v), config.version_of(v), config.nodes(), cell,
                                   theta, move_s=1 / speed, wait_s=1 / speed,
                                   action_s=action_s / speed, recheck_s=0.1 / speed,
                                   world=world, who=v.robot_id, delay_s=delay))
    return vehicles


def _jitter(rng: random.Random, spread_s: float) -> Callable[[int], float]:
    """Per-edge extra time U(-spread, +spread) s (the edge count is not needed: a stream)."""
    return lambda _edge: rng.uniform(-spread_s, spread_s)


def shift_starts(config: GatewayConfig) -> dict[int, tuple[Cell, int | None]]:
    """Where the robots of the lifelong shift ``config`` describes start: (cell, heading)."""
    shift = shift_from(config)
    return {r: (shift.grid.cell(c), shift.headings[r] if shift.headings else None)
            for r, c in enumerate(shift.starts)}


def driven_actions(vehicle: VdaVehicle) -> list[int]:
    """The gateway's action numbers of the edges ``vehicle`` drove, in order (an order named
    ``<plan key>.<first action>`` holds consecutive actions: a lifelong shift's, or a plan's
    without ``drop_waits``)."""
    out = []
    for order_id, seq in vehicle.driven:
        parsed = parse_order_id(order_id)
        if parsed is not None:
            out.append(parsed[1] + (seq - 1) // 2)
    return out
