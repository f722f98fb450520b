"""The robot client against a scripted protocol-v1 gateway.

Real parts: protocol models, the Kobuki driver on a real pty, the odometry, the runner; in the
real-time test also websockets on 127.0.0.1 and the AprilTag localiser on rendered frames. The
other tests run in virtual time (a ``looptime`` loop, the client's injectable clock and
connector, the gateway in memory), so their waits cost no wall time. Simulated: the Kobuki's
motors (tests/robot_client/kobuki_side.py) and the camera (frames rendered at the simulated
base's true pose).
"""

from __future__ import annotations

import asyncio
import math
import os
from collections.abc import AsyncIterator, Callable, Coroutine
from contextlib import asynccontextmanager
from dataclasses import dataclass
from typing import Any

import pytest

from gateway.server.clock import LoopClock, run_virtual
from protocol import (
    Ack,
    Action,
    ActionRefused,
    Blocked,
    CancelAction,
    Cancelled,
    Error,
    ErrorCode,
    Finished,
    Hello,
    Pose,
    Resume,
    Started,
    State,
    Unblocked,
    Welcome,
)
from protocol.messages import Heading
from robot_client.client import RobotClient, build_client, websocket_connect
from robot_client.config import load_settings
from robot_client.floor import FloorGrid
from robot_client.frames import CapturedFrame, monotonic_ms
from robot_client.kobuki import KobukiSerial
from robot_client.odometry import wrap_angle
from tests.robot_client.floor_render import FloorRenderer
from tests.robot_client.kobuki_side import SimulatedBase
from tests.robot_client.mini_gateway import Conn, MiniGateway
from tests.robot_client.on_pty import client_on_pty

FLOOR = FloorGrid(5, 4, 0.4, 0.12)
RENDERER = FloorRenderer(5, 4, 0.4, 0.12)
TOKEN = "robot-3-secret"
# Real time on a shared machine: a late control tick lets the simulated base run on with its
# last command, so arrival is checked to 3 cm here (the lockstep runner tests check 12 mm).
ARRIVED_M = 0.03


class RenderedFrames:
    """Camera stand-in: the floor rendered at the simulated base's true pose."""

    def __init__(self, sim: SimulatedBase) -> None:
        self.sim = sim
        self.frames = 0

    def read(self) -> CapturedFrame | None:
        self.frames += 1
        t_ms = monotonic_ms()
        return CapturedFrame(RENDERER.view(self.sim.x, self.sim.y, self.sim.theta, noise=4.0,
                                           blur=3, seed=self.frames), t_ms)

    def close(self) -> None:
        pass


@dataclass
class Robot:
    gateway: MiniGateway
    client: RobotClient
    sim: SimulatedBase
    frames: RenderedFrames | None

    def at(self, cell: tuple[int, int]) -> float:
        """True distance of the simulated base from the centre of ``cell``."""
        x, y = FLOOR.centre(cell)
        return math.hypot(self.sim.x - x, self.sim.y - y)


def action(i: int, src: tuple[int, int], dst: tuple[int, int], h0: Heading | None,
           h1: Heading | None) -> dict[str, Any]:
    """Fields of action i of robot 3 in plan 0."""
    return {"action_id": f"0.3.{i}", "sequence": i, "src": Pose(cell=src, heading=h0),
            "dst": Pose(cell=dst, heading=h1), "duration_ms": 1000.0}


@asynccontextmanager
async def scripted_robot(token: str = TOKEN, *, virtual: bool) -> AsyncIterator[Robot]:
    """Robot 3 on cell (1, 1) facing E, and the scripted gateway it connects to: over
    websockets with the camera in real time, or in memory without a camera in virtual time
    (run it under :func:`run_virtual`)."""
    gateway = MiniGateway(TOKEN)
    url = "ws://in-memory/" if virtual else f"ws://127.0.0.1:{await gateway.start()}/"
    sim = SimulatedBase(x=0.4, y=-0.4, theta=0.0)  # centre of cell (1, 1), facing E
    frames = None if virtual else RenderedFrames(sim)
    settings = load_settings(
        None, robot_id=3, token=token, gateway_url=url,
        grid_width=5, grid_height=4, cell_m=0.4, tag_size_m=0.12, start_x=1, start_y=1,
        max_speed_m_s=0.4, linear_gain=4.0, max_turn_rad_s=2.0, camera_period_ms=50,
        reconnect_min_s=0.1, reconnect_max_s=0.3, ping_interval_s=1.0, ping_timeout_s=1.0,
        bumper_pause_ms=400.0)

    def build(base: KobukiSerial) -> RobotClient:
        return build_client(settings, base, frames, clock=LoopClock() if virtual else None,
                            connect=gateway.connect if virtual else websocket_connect)

    try:
        async with client_on_pty(sim, build) as client:
            yield Robot(gateway, client, sim, frames)
    finally:
        await gateway.close()


@pytest.fixture
async def robot() -> AsyncIterator[Robot]:
    """The real-time setup (websockets, camera)."""
    async with scripted_robot(virtual=False) as r:
        yield r


Scripted = Callable[[Robot], Coroutine[Any, Any, None]]


def in_virtual_time(token: str = TOKEN) -> Callable[[Scripted], Callable[[], None]]:
    """Make ``test(robot)`` a test run in virtual time against :func:`scripted_robot` (with
    ``token``)."""

    def wrap(test: Scripted) -> Callable[[], None]:
        def run() -> None:
            async def main() -> None:
                async with scripted_robot(token, virtual=True) as robot:
                    await test(robot)

            run_virtual(main())

        run.__name__, run.__doc__ = test.__name__, test.__doc__
        return run

    return wrap


async def handshake(robot: Robot, **welcome: object) -> tuple[Conn, Hello]:
    conn = await robot.gateway.accept()
    hello = await conn.expect(Hello)
    fields: dict[str, Any] = {"robot_id": 3, "start": Pose(cell=(1, 1), heading="E"),
                              "plan": 0, "state_period_ms": 200.0, **welcome}
    await conn.send(Welcome, **fields)
    return conn, hello


async def holds(robot: Robot, ids: list[str]) -> None:
    """Wait until the robot holds exactly ``ids`` (protocol v3 sends no ``ack`` to wait for)."""
    async with asyncio.timeout(10):
        while [a.action_id for a in robot.client.held] != ids:
            await asyncio.sleep(0.01)


async def test_executes_acknowledges_and_drops_duplicates(robot: Robot) -> None:
    conn, hello = await handshake(robot)
    assert hello.robot_id == 3 and hello.pose == Pose(cell=(1, 1), heading="E")
    assert hello.acked == [] and hello.finished == [] and hello.current is None

    await conn.send(Action, **action(0, (1, 1), (2, 1), "E", "E"))
    await conn.send(Action, **action(0, (1, 1), (2, 1), "E", "E"))  # duplicate dispatch
    await conn.expect(Started, "0.3.0")  # (protocol v3: started acknowledges it)
    done = await conn.expect(Finished, "0.3.0")
    assert done.pose == Pose(cell=(2, 1), heading="E")
    assert robot.at((2, 1)) < ARRIVED_M

    await conn.send(Action, **action(1, (2, 1), (2, 1), "E", "N"))  # turn left
    await conn.expect(Started, "0.3.1")
    turned = await conn.expect(Finished, "0.3.1")
    assert turned.pose == Pose(cell=(2, 1), heading="N")
    assert abs(wrap_angle(robot.sim.theta - math.pi / 2)) < math.radians(4)

    # A late duplicate of a finished action: its finish repeated, never re-executed.
    await conn.send(Action, **action(0, (1, 1), (2, 1), "E", "E"))
    await conn.expect(Finished, "0.3.0")
    await asyncio.sleep(0.3)
    async with asyncio.timeout(10):  # snapshots every 200 ms: one soon reports idle
        while (state := await conn.expect(State)).activity != "idle":
            pass
    assert state.robot_id == 3 and state.current is None
    assert state.battery == pytest.approx((16.0 - 13.2) / (16.5 - 13.2))
    assert [m.action_id for m in conn.of_type(Started)] == ["0.3.0", "0.3.1"]
    assert not conn.of_type(Ack) and {m.v for m in conn.received} == {3}  # protocol v3
    assert robot.at((2, 1)) < ARRIVED_M
    seqs = [m.seq for m in conn.received]
    assert seqs == sorted(seqs) and len(set(seqs)) == len(seqs) and hello.seq == 0
    assert len({m.msg_id for m in conn.received}) == len(conn.received)
    assert {"running", "idle"} <= {s.activity for s in conn.of_type(State)}
    assert robot.frames is not None and robot.frames.frames > 5
    assert robot.client.body.localiser.last_fix is not None


@in_virtual_time()
async def test_link_loss_finishes_the_current_action_then_stops(robot: Robot) -> None:
    conn, _ = await handshake(robot)
    await conn.send(Action, **action(0, (1, 1), (2, 1), "E", "E"))
    await conn.send(Action, **action(1, (2, 1), (3, 1), "E", "E"))
    await conn.expect(Started, "0.3.0")
    await holds(robot, ["0.3.1"])
    robot.gateway.refuse = True
    await conn.ws.close(1006, "link lost")  # the link dies without a close frame
    # The robot completes action 0 on its own...
    async with asyncio.timeout(10):
        while robot.client.body.runner.busy:
            await asyncio.sleep(0.05)
    assert robot.at((2, 1)) < ARRIVED_M
    # ...and stops: action 1 does not start while the gateway is unreachable.
    await asyncio.sleep(0.5)
    assert robot.at((2, 1)) < ARRIVED_M and robot.sim.command == (0, 0)
    attempts = robot.gateway.attempts
    assert attempts >= 2  # it kept trying to reconnect

    robot.gateway.refuse = False
    conn2 = await robot.gateway.accept()
    hello = await conn2.expect(Hello)
    assert hello.finished == ["0.3.0"] and hello.acked == ["0.3.1"]
    assert hello.current is not None and hello.current.action_id == "0.3.1"
    assert hello.current.state == "received" and hello.pose == Pose(cell=(2, 1), heading="E")
    await conn2.send(Welcome, robot_id=3, plan=0, state_period_ms=500.0,
                     resend=[Action(msg_id="r1", seq=0, **action(1, (2, 1), (3, 1), "E", "E"))])
    await conn2.expect(Started, "0.3.1")
    await conn2.expect(Finished, "0.3.1")
    assert robot.at((3, 1)) < ARRIVED_M
    assert len(conn2.of_type(Started)) == 1


@in_virtual_time()
async def test_pause_cancel_and_a_bumper_hit(robot: Robot) -> None:
    conn, _ = await handshake(robot, paused=True, state_period_ms=60000.0)  # one snapshot only
    await conn.send(Action, **action(0, (1, 1), (2, 1), "E", "E"))
    await holds(robot, ["0.3.0"])
    await asyncio.sleep(0.3)
    # paused: the action is held, not started
    assert robot.at((1, 1)) < 0.005 and not conn.of_type(Started)
    await conn.send(CancelAction, action_id="0.3.0")
    cancelled = await conn.expect(Cancelled, "0.3.0")
    assert cancelled.pose is not None and cancelled.pose.cell == (1, 1)
    await conn.send(Resume)
    # an omni move (no headings): spin to S, then drive (a turning move would be refused:
    # the robot faces E)
    await conn.send(Action, **action(1, (1, 1), (1, 2), None, None))
    await conn.expect(Started, "0.3.1")
    await asyncio.sleep(0.3)
    robot.sim.bumper = 0x04  # left bumper for 100 ms
    await asyncio.sleep(0.1)
    robot.sim.bumper = 0
    # The bumper pause during a move is a stop on the way (v2: blocked, then unblocked), and
    # immediate snapshots say so too.
    hit = await conn.expect(State)
    while hit.activity != "blocked":  # skip the snapshot sent right after welcome
        hit = await conn.expect(State)
    assert hit.current is not None and hit.current.action_id == "0.3.1"
    assert hit.current.state == "blocked"
    resumed = await conn.expect(State)
    assert resumed.activity == "running" and resumed.current is not None
    await conn.expect(Finished, "0.3.1")
    # after the 400 ms pause it went on and still reached the target
    assert robot.at((1, 2)) < ARRIVED_M
    assert [m.action_id for m in conn.of_type(Started)] == ["0.3.1"]
    assert [m.action_id for m in conn.of_type(Blocked)] == ["0.3.1"]
    assert [m.action_id for m in conn.of_type(Unblocked)] == ["0.3.1"]


@in_virtual_time()
async def test_a_cancel_of_a_bumper_stopped_move_drives_back_then_confirms(robot: Robot) -> None:
    # a replan cancels a move the bumper stopped on the way: the robot goes back to the move's
    # source cell and heading, and only then confirms (the executor plans from that cell)
    conn, _ = await handshake(robot, state_period_ms=60000.0)
    await conn.send(Action, **action(0, (1, 1), (2, 1), "E", "E"))
    await conn.send(Action, **action(1, (2, 1), (3, 1), "E", "E"))  # lookahead: queued
    await conn.expect(Started, "0.3.0")
    async with asyncio.timeout(10):
        while robot.sim.x < 0.4 + 0.12:  # well on the way to (2, 1)
            await asyncio.sleep(0.01)
    robot.sim.bumper = 0x02
    await conn.expect(Blocked, "0.3.0")
    await conn.send(CancelAction, action_id="0.3.0")
    # the queued action behind it is dropped at once; the stopped move once back
    await conn.expect(Cancelled, "0.3.1")
    await asyncio.sleep(0.2)
    robot.sim.bumper = 0  # the obstacle stays in front for a while: the way back is free
    done = await conn.expect(Cancelled, "0.3.0")
    assert done.pose == Pose(cell=(1, 1), heading="E")
    assert robot.at((1, 1)) < ARRIVED_M
    assert abs(wrap_angle(robot.sim.theta)) < math.radians(4)
    await asyncio.sleep(0.3)
    assert not conn.of_type(Finished) and not conn.of_type(Unblocked)
    assert robot.sim.command == (0, 0) and not robot.client.body.runner.busy
    # the replan's first action from there runs as usual
    await conn.send(Action, **action(0, (1, 1), (2, 1), "E", "E") | {"action_id": "1.3.0"})
    await conn.expect(Finished, "1.3.0")
    assert robot.at((2, 1)) < ARRIVED_M


@in_virtual_time()
async def test_a_move_that_does_not_start_from_the_robots_heading_is_refused(
        robot: Robot) -> None:
    conn, _ = await handshake(robot, state_period_ms=60000.0)
    await conn.send(Action, **action(0, (1, 1), (1, 0), "N", "N"))  # the robot faces E
    await conn.send(Action, **action(1, (1, 0), (1, 0), "N", "W"))
    refused = await conn.expect(ActionRefused, "0.3.0")
    assert refused.code == "pose_mismatch" and refused.pose == Pose(cell=(1, 1), heading="E")
    assert refused.detail == ("it starts at [1, 1] facing N, but the robot will stand at "
                              "[1, 1] facing E")
    behind = await conn.expect(ActionRefused, "0.3.1")
    assert behind.code == "queued_behind"
    await asyncio.sleep(0.3)
    assert not conn.of_type(Ack) and not conn.of_type(Started)
    assert robot.at((1, 1)) < 0.005 and robot.sim.command == (0, 0)
    # the plan that turns first is taken
    await conn.send(Action, **action(0, (1, 1), (1, 1), "E", "N") | {"action_id": "1.3.0"})
    await conn.expect(Finished, "1.3.0")


@in_virtual_time()
async def test_a_cancel_drops_the_queued_actions_behind_it(robot: Robot) -> None:
    # lookahead dispatch: the robot holds a queue; a cancelled action takes the ones queued
    # behind it along (they cannot run without it), and each is confirmed
    conn, _ = await handshake(robot, paused=True, state_period_ms=60000.0)
    cells = [(1, 1), (2, 1), (3, 1), (4, 1)]
    for i in range(3):
        await conn.send(Action, **action(i, cells[i], cells[i + 1], "E", "E"))
    await holds(robot, ["0.3.0", "0.3.1", "0.3.2"])
    assert [a.action_id for a in robot.client.held] == ["0.3.0", "0.3.1", "0.3.2"]
    await conn.send(CancelAction, action_id="0.3.1")
    await conn.expect(Cancelled, "0.3.1")
    await conn.expect(Cancelled, "0.3.2")
    await conn.send(CancelAction, action_id="0.3.2")  # the gateway's own cancel: stale
    assert [a.action_id for a in robot.client.held] == ["0.3.0"]
    # an abandoned replan dispatches a cancelled action again: it is held again, in order
    await conn.send(Action, **action(1, cells[1], cells[2], "E", "E"))
    await holds(robot, ["0.3.0", "0.3.1"])
    await asyncio.sleep(0.2)
    assert [m.action_id for m in conn.of_type(Cancelled)] == ["0.3.1", "0.3.2"]
    assert not conn.of_type(Started) and robot.at((1, 1)) < 0.005  # paused: nothing moved


@in_virtual_time("wrong-token")
async def test_a_refused_token_is_retried_with_backoff_and_never_moves(robot: Robot) -> None:
    await asyncio.sleep(0.8)
    # backoff 0.1 s growing to 0.3 s: a handful of attempts, not a tight loop
    assert 2 <= robot.gateway.attempts <= 12
    assert robot.gateway.connections.empty()
    assert robot.at((1, 1)) < 0.001 and robot.sim.command == (0, 0)


def test_example_config_file_loads() -> None:
    path = os.path.join(os.path.dirname(__file__), "..", "..", "deploy", "robot.example.toml")
    settings = load_settings(None, config_file=path)
    assert settings.floor() == FloorGrid(8, 6, 0.4, 0.12)
    assert settings.token.get_secret_value() == "change-me"


@in_virtual_time()
async def test_a_gateway_that_predates_v3_gets_a_v2_robot(robot: Robot) -> None:
    # a gateway that speaks v1 and v2 only refuses the v3 hello as unsupported_version: the
    # robot says hello again in v2 on the same link and acknowledges with ack from then on
    conn = await robot.gateway.accept()
    hello = await conn.expect(Hello)
    assert hello.v == 3
    await conn.send(Error, v=2, code=ErrorCode.UNSUPPORTED_VERSION, ref=hello.msg_id,
                    detail="protocol version 3 not supported (this side speaks 1 and 2)")
    again = await conn.expect(Hello)
    assert again.v == 2 and again.robot_id == 3
    await conn.send(Welcome, v=2, robot_id=3, start=Pose(cell=(1, 1), heading="E"), plan=0,
                    state_period_ms=200.0)
    await conn.send(Action, v=2, **action(0, (1, 1), (2, 1), "E", "E"))
    ack = await conn.expect(Ack, "0.3.0")
    assert ack.v == 2
    await conn.expect(Finished, "0.3.0")
    assert {m.v for m in conn.received[1:]} == {2}
