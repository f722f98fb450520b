"""robot_client against the real gateway (gateway.server) over websockets on 127.0.0.1.

The gateway loads a one-robot plan on the shipped ``lab`` map and dispatches it; the robot is
the real client with the Kobuki driver on a pty whose motors are simulated
(tests/robot_client/kobuki_side.py) and a camera rendered from the simulated pose.
"""

from __future__ import annotations

import asyncio
import math
import os

from gateway.server.config import GatewayConfig, TokensConfig
from gateway.server.gateway import Gateway
from protocol import LoadPlan, Start
from robot_client.client import build_client
from robot_client.config import load_settings
from robot_client.floor import FloorGrid
from robot_client.frames import CapturedFrame, monotonic_ms
from robot_client.kobuki import KobukiSerial
from robot_client.odometry import wrap_angle
from tests.robot_client.floor_render import FloorRenderer
from tests.robot_client.kobuki_side import SimulatedBase, run_realtime

LAB = FloorGrid(14, 10, 0.4, 0.12)  # the lab map is 14 x 10 cells


class LabFrames:
    """Camera stand-in: the lab floor rendered at the simulated base's true pose."""

    def __init__(self, sim: SimulatedBase) -> None:
        self.sim = sim
        self.renderer = FloorRenderer(14, 10, 0.4, 0.12)
        self.frames = 0

    def read(self) -> CapturedFrame | None:
        self.frames += 1
        t_ms = monotonic_ms()
        return CapturedFrame(self.renderer.view(self.sim.x, self.sim.y, self.sim.theta,
                                                noise=4.0, blur=3, seed=self.frames), t_ms)

    def close(self) -> None:
        pass


async def test_real_gateway_drives_a_robot_through_its_plan() -> None:
    config = GatewayConfig(host="127.0.0.1", port=0, state_period_ms=300.0,
                           ping_interval_s=1.0, ping_timeout_s=2.0,
                           tokens=TokensConfig(robots={"robot-0-token": 0},
                                               demo_robot_prefix=None))
    # (1, 1) -> E to (2, 1) -> wait -> N to (2, 0)
    path = [(1, 1), (2, 1), (2, 1), (2, 0)]
    master, slave = os.openpty()
    x, y = LAB.centre((1, 1))
    sim = SimulatedBase(x=x, y=y, theta=0.0)
    base = KobukiSerial(os.ttyname(slave))
    stop = asyncio.Event()
    async with Gateway(config) as gw:
        port = await gw.listen(port=0)
        code, detail = await gw.command(LoadPlan(msg_id="op-1", seq=0, map="lab",
                                                 paths=[list(path)]))
        assert code is None, detail
        settings = load_settings(
            None, robot_id=0, token="robot-0-token", gateway_url=f"ws://127.0.0.1:{port}/",
            grid_width=14, grid_height=10, cell_m=0.4, tag_size_m=0.12, start_x=1, start_y=1,
            max_speed_m_s=0.4, linear_gain=4.0, max_turn_rad_s=2.0, camera_period_ms=50,
            reconnect_min_s=0.1, reconnect_max_s=0.5)
        frames = LabFrames(sim)
        client = build_client(settings, base, frames)
        sim_task = asyncio.create_task(run_realtime(sim, master, stop))
        client_task = asyncio.create_task(client.run())
        try:
            async with asyncio.timeout(10):
                while client.sessions == 0:
                    await asyncio.sleep(0.05)
            code, detail = await gw.command(Start(msg_id="op-2", seq=1))
            assert code is None, detail
            soc_ms, makespan_ms = await asyncio.wait_for(gw.wait_done(), 30)
        finally:
            client.stop()
            await client_task
            stop.set()
            await sim_task
            base.close()
            os.close(slave)
            os.close(master)
    cx, cy = LAB.centre((2, 0))
    # real time on a shared machine: see test_client.ARRIVED_M
    assert math.hypot(sim.x - cx, sim.y - cy) < 0.03
    assert abs(wrap_angle(sim.theta - math.pi / 2)) < math.radians(4)
    # two 0.4 m moves at <= 0.4 m/s (>= 1 s each) and a 1000 ms wait, timed by the gateway
    assert makespan_ms >= 3000.0 and soc_ms == makespan_ms
    assert list(client.finished) == ["0.0.0", "0.0.1", "0.0.2"]
    assert client.body.localiser.last_fix is not None
