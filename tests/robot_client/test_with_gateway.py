"""robot_client against the real gateway (gateway.server) over websockets on 127.0.0.1.

The gateway loads a one-robot plan on the shipped ``lab`` map and dispatches it; the robot is
the real client with the Kobuki driver on a pty whose motors are simulated
(tests/robot_client/kobuki_side.py) and a camera rendered from the simulated pose.
"""

from __future__ import annotations

import asyncio
import math
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from dataclasses import dataclass

from gateway.server.config import GatewayConfig, TokensConfig
from gateway.server.gateway import Gateway
from protocol import LoadPlan, Start
from robot_client.client import RobotClient, build_client
from robot_client.config import load_settings
from robot_client.floor import FloorGrid
from robot_client.frames import CapturedFrame, monotonic_ms
from robot_client.odometry import wrap_angle
from tests.robot_client.floor_render import FloorRenderer
from tests.robot_client.kobuki_side import SimulatedBase
from tests.robot_client.on_pty import client_on_pty
from tests.robot_client.tcp_proxy import CuttableProxy

LAB = FloorGrid(14, 10, 0.4, 0.12)  # the lab map is 14 x 10 cells
TOKEN = "robot-0-token"
# real time on a shared machine: see test_client.ARRIVED_M
ARRIVED_M = 0.03


class LabFrames:
    """Camera stand-in: the lab floor rendered at the simulated base's true pose."""

    renderer: FloorRenderer | None = None

    def __init__(self, sim: SimulatedBase) -> None:
        self.sim = sim
        if LabFrames.renderer is None:
            LabFrames.renderer = FloorRenderer(14, 10, 0.4, 0.12)
        self.frames = 0

    def read(self) -> CapturedFrame | None:
        assert self.renderer is not None
        self.frames += 1
        t_ms = monotonic_ms()
        return CapturedFrame(self.renderer.view(self.sim.x, self.sim.y, self.sim.theta,
                                                noise=4.0, blur=3, seed=self.frames), t_ms)

    def close(self) -> None:
        pass


@dataclass
class Setup:
    gateway: Gateway
    proxy: CuttableProxy
    client: RobotClient
    sim: SimulatedBase

    def at(self, cell: tuple[int, int]) -> float:
        """True distance of the simulated base from the centre of ``cell``."""
        x, y = LAB.centre(cell)
        return math.hypot(self.sim.x - x, self.sim.y - y)


@asynccontextmanager
async def lab_robot(path: list[tuple[int, int]]) -> AsyncIterator[Setup]:
    """The real gateway with ``path`` loaded for robot 0, and that robot connected to it
    through a cuttable loopback proxy, standing on ``path[0]`` facing E."""
    config = GatewayConfig(host="127.0.0.1", port=0, state_period_ms=300.0,
                           ping_interval_s=1.0, ping_timeout_s=2.0,
                           tokens=TokensConfig(robots={TOKEN: 0}, demo_robot_prefix=None))
    x, y = LAB.centre(path[0])
    sim = SimulatedBase(x=x, y=y, theta=0.0)
    async with Gateway(config) as gw:
        proxy = CuttableProxy(await gw.listen(port=0))
        port = await proxy.start()
        code, detail = await gw.command(LoadPlan(msg_id="op-1", seq=0, map="lab",
                                                 paths=[list(path)]))
        assert code is None, detail
        settings = load_settings(
            None, robot_id=0, token=TOKEN, gateway_url=f"ws://127.0.0.1:{port}/",
            grid_width=14, grid_height=10, cell_m=0.4, tag_size_m=0.12, start_x=path[0][0],
            start_y=path[0][1], max_speed_m_s=0.4, linear_gain=4.0, max_turn_rad_s=2.0,
            camera_period_ms=50, reconnect_min_s=0.1, reconnect_max_s=0.3,
            bumper_pause_ms=400.0)
        try:
            async with client_on_pty(sim, lambda base: build_client(
                    settings, base, LabFrames(sim))) as client:
                async with asyncio.timeout(10):
                    while client.sessions == 0:
                        await asyncio.sleep(0.05)
                yield Setup(gw, proxy, client, sim)
        finally:
            await proxy.close()


async def test_real_gateway_drives_a_robot_through_its_plan() -> None:
    # (1, 1) -> E to (2, 1) -> wait -> N to (2, 0)
    async with lab_robot([(1, 1), (2, 1), (2, 1), (2, 0)]) as s:
        code, detail = await s.gateway.command(Start(msg_id="op-2", seq=1))
        assert code is None, detail
        async with asyncio.timeout(10):
            while s.client.body.runner.action is None:
                await asyncio.sleep(0.02)
        await asyncio.sleep(0.3)
        s.sim.bumper = 0x02  # someone bumps into the robot during its first move
        await asyncio.sleep(0.1)
        s.sim.bumper = 0
        soc_ms, makespan_ms = await asyncio.wait_for(s.gateway.wait_done(), 30)
        assert not s.client.gateway_errors  # the gateway accepted every report
        assert s.at((2, 0)) < ARRIVED_M
        assert abs(wrap_angle(s.sim.theta - math.pi / 2)) < math.radians(4)
        # two 0.4 m moves at <= 0.4 m/s (>= 1 s each), a 400 ms bumper pause and a 1000 ms
        # wait, timed by the gateway
        assert makespan_ms >= 3400.0 and soc_ms == makespan_ms
        assert list(s.client.finished) == ["0.0.0", "0.0.1", "0.0.2"]
        assert s.client.body.localiser.last_fix is not None


async def test_link_cut_mid_action_robot_finishes_offline_and_gateway_catches_up() -> None:
    async with lab_robot([(1, 1), (2, 1), (3, 1)]) as s:
        code, detail = await s.gateway.command(Start(msg_id="op-2", seq=1))
        assert code is None, detail
        async with asyncio.timeout(10):
            while s.client.body.runner.action is None:
                await asyncio.sleep(0.02)
        assert s.client.body.runner.action.action_id == "0.0.0"
        # lookahead dispatch (the gateway's default): action 1 is released at once and queued
        async with asyncio.timeout(10):
            while "0.0.1" not in s.client.known:
                await asyncio.sleep(0.02)
        s.proxy.refuse = True
        s.proxy.cut()
        # Offline, the robot completes its move, then stands still: it holds action 1 but
        # starts nothing until the gateway has welcomed it back.
        async with asyncio.timeout(10):
            while "0.0.0" not in s.client.finished:
                await asyncio.sleep(0.05)
        assert s.client.link is None and s.at((2, 1)) < ARRIVED_M
        await asyncio.sleep(0.5)
        assert s.at((2, 1)) < ARRIVED_M
        assert [a.action_id for a in s.client.held] == ["0.0.1"]
        # Back online: its hello reports the finish, the gateway applies it and dispatches on.
        s.proxy.refuse = False
        await asyncio.wait_for(s.gateway.wait_done(), 30)
        assert s.client.sessions == 2 and s.proxy.accepted >= 2
        assert not s.client.gateway_errors
        assert list(s.client.finished) == ["0.0.0", "0.0.1"]
        assert s.at((3, 1)) < ARRIVED_M
