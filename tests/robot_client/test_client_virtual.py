"""The robot client in virtual time: its injectable clock and connector let the real client
(real protocol session, Kobuki driver on a real pty, odometry, runner) run against the real
gateway over the in-memory transport on a ``looptime`` loop, so waiting costs no wall time and
timings are exact. Simulated: the Kobuki's motors (tests/robot_client/kobuki_side.py); no camera.
"""

from __future__ import annotations

import asyncio
import itertools
import math
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from dataclasses import dataclass, field

from gateway.server.clock import LoopClock, VirtualClock, run_virtual
from gateway.server.config import GatewayConfig, TokensConfig
from gateway.server.gateway import Gateway
from protocol import LoadPlan, Start
from robot_client.client import Connection, RobotClient, build_client
from robot_client.config import RobotSettings, load_settings
from robot_client.floor import FloorGrid
from tests.robot_client.kobuki_side import SimulatedBase
from tests.robot_client.on_pty import client_on_pty

LAB = FloorGrid(14, 10, 0.4, 0.12)  # the lab map is 14 x 10 cells
TOKEN = "robot-0-token"
ARRIVED_M = 0.012  # lockstep in virtual time: no scheduling stalls (the runner tests' bound)


@dataclass
class Setup:
    gateway: Gateway
    client: RobotClient
    sim: SimulatedBase
    attempts: list[float] = field(default_factory=list)
    """Virtual time of every connection attempt."""
    refuse: bool = False

    def at(self, cell: tuple[int, int]) -> float:
        x, y = LAB.centre(cell)
        return math.hypot(self.sim.x - x, self.sim.y - y)


@asynccontextmanager
async def lab_robot(path: list[tuple[int, int]], token: str = TOKEN) -> AsyncIterator[Setup]:
    """The real gateway (virtual clock) with ``path`` loaded for robot 0, and the real client
    on a pty base connected to it in memory."""
    config = GatewayConfig(port=0, map=None, policy="none", state_period_ms=300.0,
                           tokens=TokensConfig(robots={TOKEN: 0}, demo_robot_prefix=None))
    x, y = LAB.centre(path[0])
    sim = SimulatedBase(x=x, y=y, theta=0.0)
    async with Gateway(config, clock=VirtualClock()) as gw:
        code, detail = await gw.command(LoadPlan(msg_id="op-1", seq=0, map="lab",
                                                 paths=[list(path)]))
        assert code is None, detail
        setup: Setup

        async def connect(s: RobotSettings) -> Connection:
            setup.attempts.append(asyncio.get_running_loop().time())
            if setup.refuse:
                raise OSError("gateway unreachable")
            return await gw.connect(s.token.get_secret_value())

        settings = load_settings(
            None, robot_id=0, token=token, gateway_url="ws://in-memory/ws", grid_width=14,
            grid_height=10, cell_m=0.4, tag_size_m=0.12, start_x=path[0][0],
            start_y=path[0][1], max_speed_m_s=0.4, linear_gain=4.0, max_turn_rad_s=2.0,
            reconnect_min_s=0.1, reconnect_max_s=0.3, bumper_pause_ms=400.0)
        async with client_on_pty(sim, lambda base: build_client(
                settings, base, None, clock=LoopClock(), connect=connect)) as client:
            setup = Setup(gw, client, sim)
            yield setup


async def until(predicate: object, timeout_s: float = 30.0) -> None:
    async with asyncio.timeout(timeout_s):
        while not predicate():  # type: ignore[operator]
            await asyncio.sleep(0.02)


def test_link_cut_mid_action_in_virtual_time() -> None:
    async def main() -> None:
        async with lab_robot([(1, 1), (2, 1), (3, 1)]) as s:
            await until(lambda: s.client.sessions == 1)
            code, detail = await s.gateway.command(Start(msg_id="op-2", seq=1))
            assert code is None, detail
            await until(lambda: s.client.body.runner.action is not None)
            assert s.client.body.runner.action.action_id == "0.0.0"
            # lookahead dispatch (the gateway's default): action 1 is queued at once
            await until(lambda: [a.action_id for a in s.client.held] == ["0.0.1"])
            s.refuse = True
            assert s.client.link is not None
            cut_at = asyncio.get_running_loop().time()
            await s.client.link.close(1011, "cut")
            # offline, the robot completes its move, then stands still holding action 1
            await until(lambda: "0.0.0" in s.client.finished)
            assert s.client.link is None and s.at((2, 1)) < ARRIVED_M
            await asyncio.sleep(0.5)
            assert s.at((2, 1)) < ARRIVED_M and s.sim.command == (0, 0)
            assert [a.action_id for a in s.client.held] == ["0.0.1"]
            s.refuse = False
            soc_ms, makespan_ms = await asyncio.wait_for(s.gateway.wait_done(), 30)
            assert s.client.sessions == 2 and not s.client.gateway_errors
            assert s.client.finished == ["0.0.0", "0.0.1"]
            assert s.at((3, 1)) < ARRIVED_M
            # it kept trying with backoff: 0.1 s growing to 0.3 s between tries (the first
            # after a random delay below 0.1 s), then reconnected at once
            tries = [t for t in s.attempts if t >= cut_at]
            gaps = [round(b - a, 4) for a, b in itertools.pairwise(tries)]
            assert len(tries) >= 5 and gaps[:3] == [0.1, 0.1618, 0.2618]
            assert set(gaps[3:]) <= {0.3}
            # the hello reported 0.0.1 held: it was not resent (acknowledged, not lost)
            assert s.gateway.engine.robot(0).applied == {"0.0.0": "finished",
                                                         "0.0.1": "finished"}
            # two 0.4 m moves at <= 0.4 m/s, the second after the 0.5 s outage at least
            assert makespan_ms >= 2500.0 and soc_ms == makespan_ms

    run_virtual(main())


def test_a_refused_robot_retries_with_backoff_in_virtual_time() -> None:
    async def main() -> tuple[list[float], SimulatedBase, float]:
        async with lab_robot([(1, 1), (2, 1)]) as s:
            s.refuse = True
            t0 = asyncio.get_running_loop().time()
            await asyncio.sleep(0.8)
            return [t - t0 for t in s.attempts], s.sim, s.at((1, 1))

    attempts, sim, away = run_virtual(main())
    # backoff(0.1, 0.1, 0.3): a random first delay r in [0, 0.1), then 0.1, 0.1618, 0.2618,
    # 0.3, ...: tries at 0, r, r + 0.1, r + 0.2618, r + 0.5236; the next one at r + 0.8236
    assert len(attempts) == 5
    gaps = [b - a for a, b in itertools.pairwise(attempts[1:])]
    assert [round(g, 4) for g in gaps] == [0.1, 0.1618, 0.2618]
    assert away < 0.001 and sim.command == (0, 0)
