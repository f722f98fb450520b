"""One real robot_client for `fleetgate conformance robot --command`: the real client, driver,
odometry and runner, on a pseudo-terminal whose Kobuki motors are simulated
(tests/robot_client/kobuki_side.py); no camera. Mock only what cannot exist here: the motors.

Usage: python tests/conformance/kobuki_robot.py URL TOKEN ROBOT_ID
"""

from __future__ import annotations

import asyncio
import os
import signal
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from robot_client.client import build_client
from robot_client.config import load_settings
from robot_client.kobuki import KobukiSerial
from tests.robot_client.kobuki_side import SimulatedBase, run_realtime

CELL_M = 0.15
"""A small floor grid (5 x 1 cells) so that moves are quick."""


async def main(url: str, token: str, robot_id: int) -> None:
    """Run the robot until SIGTERM."""
    master, slave = os.openpty()
    base = KobukiSerial(os.ttyname(slave))
    settings = load_settings(
        None, robot_id=robot_id, token=token, gateway_url=url, grid_width=5, grid_height=1,
        cell_m=CELL_M, tag_size_m=0.05, no_camera=True, max_speed_m_s=0.5, linear_gain=6.0,
        max_turn_rad_s=3.0, reconnect_min_s=0.1, reconnect_max_s=0.3, ping_interval_s=1.0,
        ping_timeout_s=2.0)
    x, y = settings.floor().centre((0, 0))
    sim = SimulatedBase(x=x, y=y, theta=0.0)
    client = build_client(settings, base, None)
    stop = asyncio.Event()
    loop = asyncio.get_running_loop()
    loop.add_signal_handler(signal.SIGTERM, stop.set)
    motors = asyncio.create_task(run_realtime(sim, master, stop))
    robot = asyncio.create_task(client.run())
    await stop.wait()
    client.stop()
    await robot
    await motors
    base.close()
    os.close(slave)
    os.close(master)


if __name__ == "__main__":
    asyncio.run(main(sys.argv[1], sys.argv[2], int(sys.argv[3])))
