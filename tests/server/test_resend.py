"""A reconnect resends ONLY what the robot does not hold (protocol.gateway_session), over real
websockets on 127.0.0.1: scripted message by message, and with the simulated fleet (the shared
robot session) losing its links mid-run."""

from __future__ import annotations

import asyncio
from collections import Counter
from typing import Any, cast

import pytest
from websockets.asyncio.client import ClientConnection, connect

from gateway.server.clock import VirtualClock
from gateway.server.gateway import Gateway
from protocol import (
    Ack,
    Action,
    Activity,
    Finished,
    Hello,
    LoadPlan,
    RobotMessage,
    Start,
    Started,
    Welcome,
)
from protocol.messages import ProtocolVersion
from protocol.robot_session import RobotEffect, RobotSession, Send
from sim_clients.fleet import SimFleet
from tests.server.conftest import LAB_PATHS, make_config
from tests.server.robots import Peer, TestRobot

pytestmark = pytest.mark.looptime  # virtual time over real websockets


async def ws(gw: Gateway, token: str) -> ClientConnection:
    return await connect(f"ws://127.0.0.1:{gw.port}/ws",
                         additional_headers={"Authorization": f"Bearer {token}"}, proxy=None)


async def until(predicate: Any, timeout: float = 5.0) -> None:
    async with asyncio.timeout(timeout):
        while not predicate():
            await asyncio.sleep(0.01)


async def hello(peer: Peer, **fields: Any) -> Welcome:
    await peer.send(Hello, robot_id=0, **fields)
    welcome: Welcome = await peer.expect(Welcome)
    return welcome


async def test_reconnect_resends_only_the_actions_the_robot_does_not_hold() -> None:
    async with Gateway(make_config(dispatch_lookahead=1), clock=VirtualClock()) as gw:
        await gw.listen()
        code, detail = await gw.command(LoadPlan(msg_id="l", seq=0, map="lab",
                                                 paths=LAB_PATHS[:1]))
        assert code is None, detail
        robot = Peer(await ws(gw, "demo-robot-0"), "a")
        assert (await hello(robot)).resend == []
        await gw.command(Start(msg_id="s", seq=1))
        got = [(await robot.expect(Action)).action_id for _ in range(2)]
        assert got == ["0.0.0", "0.0.1"]
        await robot.send(Ack, action_id="0.0.0")  # the ack of 0.0.1 is lost with the link
        await robot.send(Started, action_id="0.0.0")
        await until(lambda: gw.engine.robot(0).held["0.0.0"].phase == "running")
        await robot.link.close()
        await until(lambda: gw.engine.robot(0).link is None)
        held = gw.engine.robot(0).held
        assert {aid: h.acked for aid, h in held.items()} == {"0.0.0": True, "0.0.1": False}

        # back: it runs 0.0.0 and holds 0.0.1 (received; its ack was lost): nothing to resend
        running = Activity(action_id="0.0.0", state="running")
        again = Peer(await ws(gw, "demo-robot-0"), "b")
        welcome = await hello(again, acked=["0.0.0", "0.0.1"], current=running)
        assert welcome.resend == []
        assert all(h.acked for h in gw.engine.robot(0).held.values())
        await again.link.close()
        await until(lambda: gw.engine.robot(0).link is None)

        # back after a restart that lost its queue: 0.0.1 was acknowledged before, but the
        # robot no longer holds it, so it is resent; 0.0.0, which it still runs, is not
        third = TestRobot(await ws(gw, "demo-robot-0"), 0)
        welcome = await third.hello(current=running)
        assert [a.action_id for a in welcome.resend] == ["0.0.1"]
        await third.send(Finished, action_id="0.0.0")
        task = asyncio.create_task(third.run())
        await asyncio.wait_for(gw.wait_done(), 10)
        task.cancel()
        assert third.finished == [f"0.0.{i}" for i in range(1, 5)]


@pytest.mark.parametrize("versions", [(3, 2, 3), (2, 3, 2)])
async def test_a_fleet_that_loses_its_links_is_resent_nothing_it_holds(
        versions: tuple[int, int, int]) -> None:
    # the simulated robots (the shared robot session) over websockets, lookahead dispatch,
    # protocol v2 and v3 robots side by side: every reconnect happens while robot 0 holds a
    # queued action (which a v3 robot never acknowledged: no ack), which is not resent
    config = make_config(dispatch_lookahead=1, speed=10.0, policy="none")
    async with Gateway(config, clock=VirtualClock()) as gw:
        port = await gw.listen()

        async def connect_robot(token: str) -> ClientConnection:
            return await connect(f"ws://127.0.0.1:{port}/ws", proxy=None,
                                 additional_headers={"Authorization": f"Bearer {token}"})

        code, detail = await gw.command(LoadPlan(msg_id="l", seq=0, map="lab",
                                                 paths=LAB_PATHS))
        assert code is None, detail
        fleet = SimFleet(connect_robot, range(3), clock=gw.clock, send_state=False,
                         reconnect_delay_s=0.05)
        sessions = [Recording(r, version=cast(ProtocolVersion, v))
                    for r, v in enumerate(versions)]
        for r, session in enumerate(sessions):
            fleet.add_robot(r).session = session
        fleet.place_all([p[0] for p in LAB_PATHS])
        await fleet.start()
        await fleet.wait_connected(10)
        assert await gw.command(Start(msg_id="s", seq=1)) == (None, "started")
        robot = fleet.robots[0]
        for _ in range(2):  # robot 0 (5 actions) loses its link twice, holding a queued one
            await until(lambda: len(robot.session.queue) == 1 and robot.connected.is_set())
            await robot.drop_link()
            await until(lambda: robot.connected.is_set())
        soc, _ = await asyncio.wait_for(gw.wait_done(), 30)
        await fleet.stop()
    assert fleet.stats.reconnects == 2 and fleet.stats.errors == []
    assert fleet.stats.duplicates == 0  # nothing it held was sent to it again
    assert len(fleet.stats.received) == sum(len(p) - 1 for p in LAB_PATHS)
    assert soc >= 1000.0 * sum(len(p) - 1 for p in LAB_PATHS)
    for session, path in zip(sessions, LAB_PATHS, strict=True):
        kinds = Counter(m.type for m in session.sent)
        assert {m.v for m in session.sent} == {session.version}
        assert kinds["started"] == kinds["finished"] == len(path) - 1
        # v2: an ack per action received (what a cut link swallowed excepted); v3: none
        assert (kinds["ack"] >= len(path) - 1 - 2) if session.version == 2 else \
            kinds["ack"] == 0


class Recording(RobotSession):
    """The shared robot session, keeping every message it sent."""

    def __init__(self, robot_id: int, version: ProtocolVersion) -> None:
        super().__init__(robot_id, version=version)
        self.sent: list[RobotMessage] = []

    def drain(self) -> list[RobotEffect]:
        out = super().drain()
        self.sent += [e.message for e in out if isinstance(e, Send)]
        return out
