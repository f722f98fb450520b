"""A robot refuses an action (protocol v2 ``refused``), over real websockets on 127.0.0.1: the
simulated fleet (the shared robot session) checks each action's start pose and heading against
its own; the gateway takes the action back, not executed, without an error, and the operator
sees why."""

from __future__ import annotations

import asyncio
from typing import Any

import pytest

from gateway.server.clock import VirtualClock
from gateway.server.gateway import Gateway
from protocol import Action, ActionRefused, ErrorCode, Event, LoadPlan, Start, Started
from sim_clients.fleet import SimFleet
from tests.server.conftest import Connect, connector, make_config, virtual_gateway
from tests.server.robots import Peer, TestRobot

# Robot 0 drives east along row 0; robot 1 turns twice on (5, 1), to west, and drives to (4, 1).
PATHS = [[(0, 0), (1, 0), (2, 0)], [(5, 1), (5, 1), (5, 1), (4, 1)]]
HEADINGS = [[0, 0, 0], [0, 3, 2, 2]]


async def until(predicate: Any, timeout: float = 10.0) -> None:
    async with asyncio.timeout(timeout):
        while not predicate():
            await asyncio.sleep(0.01)


@pytest.mark.looptime  # virtual time over real websockets
async def test_a_sim_robot_facing_elsewhere_refuses_and_the_operator_sees_why() -> None:
    async with Gateway(make_config(speed=10.0, policy="none", dispatch_lookahead=1),
                       clock=VirtualClock()) as gw:
        await gw.listen()
        connect: Connect = connector(gw)
        plan = LoadPlan(msg_id="l", seq=0, map="lab", paths=PATHS, headings=HEADINGS)
        assert (await gw.command(plan))[0] is None
        operator = Peer(await connect("demo-operator"), "op")
        fleet = SimFleet(connect, range(2), clock=gw.clock, send_state=False)
        await fleet.start()
        await fleet.wait_connected(10)  # placed as the welcome says; now robot 0 turns round:
        fleet.place_all([p[0] for p in PATHS], [2, 0])  # it faces west, not east
        assert await gw.command(Start(msg_id="s", seq=1)) == (None, "started")
        refused: Event = await operator.expect(Event)
        while refused.event != "refused":
            refused = await operator.expect(Event)
        assert (refused.robot, refused.plan, refused.action) == (0, 0, 0)
        assert refused.reason == ("pose_mismatch: it starts at [0, 0] facing E, but the robot "
                                  "will stand at [0, 0] facing W")
        ex = gw.engine.executor
        assert ex is not None
        await until(lambda: ex.completion_ms(1) > 0 and not gw.engine.robot(1).held)
        await asyncio.sleep(0.2)
        await fleet.stop()
    # robot 1 ran its plan (a turn and a move); robot 0 never moved and got no error
    assert ex.robot_cell(1) == (4, 1) and ex.robot_heading(1) == 2
    assert not ex.has_started(0, 0, 0) and ex.robot_cell(0) == (0, 0)
    assert fleet.stats.errors == [
        "robot 0 refused 0.0.0: it starts at [0, 0] facing E, but the robot will stand at "
        "[0, 0] facing W",
        "robot 0 refused 0.0.1: action 0.0.0 before it was refused"]
    assert fleet.robots[0].cell == (0, 0)


@pytest.mark.looptime  # virtual time over real websockets
async def test_the_gateway_takes_a_refusal_of_a_started_action_as_an_error() -> None:
    async with virtual_gateway() as (gateway, ws_connect):
        assert (await gateway.command(LoadPlan(msg_id="l", seq=0, map="lab", paths=PATHS,
                                               headings=HEADINGS)))[0] is None
        robot = TestRobot(await ws_connect("demo-robot-1"), 1)
        await robot.hello()
        assert await gateway.command(Start(msg_id="s", seq=1)) == (None, "started")
        action = await robot.expect(Action)
        await robot.send(Started, action_id=action.action_id)
        ref = await robot.send(ActionRefused, action_id=action.action_id, code="cannot_execute")
        err = await robot.error_for(ref)
        assert err.code is ErrorCode.REJECTED and "already started" in err.detail
