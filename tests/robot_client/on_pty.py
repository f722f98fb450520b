"""A robot client on a real Kobuki driver over a pseudo-terminal, with the simulated base
(tests/robot_client/kobuki_side.py) playing the other end on the same loop: the setup the
client tests share."""

from __future__ import annotations

import asyncio
import os
from collections.abc import AsyncIterator, Callable
from contextlib import asynccontextmanager

from robot_client.client import RobotClient
from robot_client.kobuki import KobukiSerial
from tests.robot_client.kobuki_side import SimulatedBase, run_realtime


@asynccontextmanager
async def client_on_pty(sim: SimulatedBase, build: Callable[[KobukiSerial], RobotClient]
                        ) -> AsyncIterator[RobotClient]:
    """The client ``build`` makes for a driver on a fresh pty, running (with ``sim`` on the
    pty's other end) until the block ends; then both are stopped and the pty is closed."""
    master, slave = os.openpty()
    base = KobukiSerial(os.ttyname(slave))
    stop = asyncio.Event()
    try:
        client = build(base)
        sim_task = asyncio.create_task(run_realtime(sim, master, stop))
        client_task = asyncio.create_task(client.run())
        try:
            yield client
        finally:
            client.stop()
            await client_task
            stop.set()
            await sim_task
    finally:
        base.close()
        os.close(slave)
        os.close(master)
