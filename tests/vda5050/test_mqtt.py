"""Master control and simulated vehicles through a real mosquitto: orders, reports, pause and
the connection topic; every message on the broker (captured by a listening client) validates
against the official schema of its version; the last will reaches the master."""

from __future__ import annotations

import asyncio
import json
import sys
import time

import pytest

from gateway.vda5050.broker import BrokerConfig
from gateway.vda5050.driver import MasterClient
from protocol.messages import HEADINGS
from protocol.vda5050.master import Effect, LinkState, Report, VehicleMaster
from protocol.vda5050.models import VdaVersion, dump
from protocol.vda5050.nodes import THETA, NodeMap
from protocol.vda5050.topics import VehicleTopics
from sim_clients.vda_fleet import run_fleet
from sim_clients.vda_vehicle import VdaVehicle
from sim_clients.world import World
from tests.vda5050.fleets import sniff
from tests.vda5050.loop import actions_of
from tests.vda5050.schemas import SCHEMA_DIR, assert_valid

NODES = NodeMap(cell_m=1.0, map_id="lab")
PATHS = [[(0, 0, 0), (1, 0, 0), (2, 0, 0), (2, 0, 1), (2, 1, 1)],
         [(0, 3, 0), (1, 3, 0), (1, 3, 0), (2, 3, 0)],
         [(5, 5, 3), (5, 4, 3), (5, 3, 3), (5, 3, 2), (4, 3, 2)]]
VERSIONS: list[VdaVersion] = ["2.0.0", "2.1.0", "2.1.0"]


async def test_plan_through_mosquitto(broker_url: str) -> None:
    config = BrokerConfig(url=broker_url)
    seen: list[tuple[str, bytes]] = []
    effects: list[tuple[str, Effect]] = []
    sniffing = asyncio.Event()
    sniffer = asyncio.create_task(sniff(config, seen, sniffing))
    await sniffing.wait()
    masters, vehicles = [], []
    world = World()
    for robot, (path, version) in enumerate(zip(PATHS, VERSIONS, strict=True)):
        topics = VehicleTopics("uagv", "v2", "fleetgate", f"sim{robot}")
        masters.append(VehicleMaster(topics, version, NODES))
        vehicle = VdaVehicle(topics, version, NODES, path[0][:2], THETA[HEADINGS[path[0][2]]],
                             move_s=0.1, wait_s=0.1, world=world, who=robot)
        vehicles.append(vehicle)
    client = MasterClient(config, masters,
                          lambda m, e: effects.append((m.topics.serial, e)))
    master_task = asyncio.create_task(client.run())
    await client.connected.wait()
    stop = asyncio.Event()
    fleet = asyncio.create_task(run_fleet(vehicles, config, stop))
    plans = [actions_of(path, robot=r) for r, path in enumerate(PATHS)]
    deadline = time.monotonic() + 20
    while sum(isinstance(e, LinkState) for _, e in effects) < 3:
        assert time.monotonic() < deadline, effects
        await asyncio.sleep(0.05)
    masters[0].pause(time.time())
    for master, actions in zip(masters, plans, strict=True):
        master.set_plan(actions)
        master.release(actions[:2], time.time())
        client.flush(master)
    await asyncio.sleep(0.5)
    assert not [e for s, e in effects if s == "sim0" and isinstance(e, Report)
                and e.kind == "finished"], "a paused vehicle does not drive"
    masters[0].resume(time.time())
    for master, actions in zip(masters, plans, strict=True):
        master.release(actions[2:], time.time())
        client.flush(master)
    finished = {a.action_id for actions in plans for a in actions}
    while finished - {e.action_id for _, e in effects
                      if isinstance(e, Report) and e.kind == "finished"}:
        assert time.monotonic() < deadline, effects
        await asyncio.sleep(0.05)
    stop.set()
    await fleet
    await asyncio.sleep(0.3)
    master_task.cancel()
    sniffer.cancel()
    for robot, actions in enumerate(plans):
        kinds = [e.kind for s, e in effects if s == f"sim{robot}" and isinstance(e, Report)]
        assert kinds == ["started", "finished"] * len(actions), kinds
        assert vehicles[robot].cell == PATHS[robot][-1][:2]
    assert client.dropped == 0 and world.collisions == []
    names = {t.rsplit("/", 1)[-1] for t, _ in seen}
    assert {"order", "instantActions", "state", "connection"} <= names
    states = [json.loads(p)["connectionState"] for t, p in seen if t.endswith("/connection")]
    assert states.count("ONLINE") == 3 and states.count("OFFLINE") == 3
    if (SCHEMA_DIR / "2.1.0").is_dir():
        for topic, payload in seen:
            assert_valid(json.loads(payload)["version"], topic.rsplit("/", 1)[-1], payload)


WILL = """
import asyncio, os, sys, time
from gateway.vda5050.broker import BrokerConfig, publish, will
from protocol.vda5050.nodes import NodeMap
from protocol.vda5050.topics import VehicleTopics
from sim_clients.vda_vehicle import VdaVehicle

async def main():
    topics = VehicleTopics("uagv", "v2", "fleetgate", "doomed")
    vehicle = VdaVehicle(topics, "2.1.0", NodeMap(1.0, "lab"), (0, 0))
    broken, online = vehicle.connect(time.time())
    config = BrokerConfig(url=sys.argv[1], keepalive_s=5)
    async with config.client("doomed", will(topics.topic("connection"), broken.message)) as c:
        publish(c, topics.topic("connection"), "connection", online.message)
        await asyncio.sleep(0.3)
        os._exit(0)  # the connection breaks without an MQTT DISCONNECT

asyncio.run(main())
"""


async def test_last_will_reaches_the_master(broker_url: str) -> None:
    config = BrokerConfig(url=broker_url)
    topics = VehicleTopics("uagv", "v2", "fleetgate", "doomed")
    links: list[LinkState] = []
    master = VehicleMaster(topics, "2.1.0", NodeMap(1.0, "lab"))
    client = MasterClient(config, [master], lambda _m, e: links.append(e)  # type: ignore
                          if isinstance(e, LinkState) else None)
    task = asyncio.create_task(client.run())
    await client.connected.wait()
    proc = await asyncio.create_subprocess_exec(sys.executable, "-c", WILL, broker_url)
    assert await proc.wait() == 0
    deadline = time.monotonic() + 10
    while [s.state for s in links] != ["ONLINE", "CONNECTIONBROKEN"]:
        assert time.monotonic() < deadline, links
        await asyncio.sleep(0.05)
    task.cancel()


async def test_malformed_messages_are_dropped_and_logged(broker_url: str,
                                                         caplog: pytest.LogCaptureFixture
                                                         ) -> None:
    config = BrokerConfig(url=broker_url)
    topics = VehicleTopics("uagv", "v2", "fleetgate", "sim0")
    master = VehicleMaster(topics, "2.1.0", NODES)
    links: list[Effect] = []
    client = MasterClient(config, [master], lambda _m, e: links.append(e))
    task = asyncio.create_task(client.run())
    await client.connected.wait()
    good = VdaVehicle(topics, "2.1.0", NODES, (0, 0)).connect(time.time())[1].message
    async with config.client("stranger") as stranger:
        await stranger.publish(topics.topic("state"), b"{not json")
        await stranger.publish(topics.topic("state"), b'{"headerId": "x"}')
        await stranger.publish(topics.topic("connection"), b"x" * 300_000)
        await stranger.publish("uagv/v2/fleetgate/unknown/state", b"{}")
        await stranger.publish(topics.topic("connection"), dump(good))
        deadline = time.monotonic() + 10
        while not links:
            assert time.monotonic() < deadline
            await asyncio.sleep(0.05)
    task.cancel()
    assert client.dropped == 3  # the unknown vehicle's topic is not even subscribed
    assert links == [LinkState(True, "ONLINE")]  # the gateway side carried on
    dropped = [r for r in caplog.records if r.getMessage() == "dropped a VDA 5050 message"]
    assert len(dropped) == 3
