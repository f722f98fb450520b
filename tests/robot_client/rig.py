"""A robot body on a real pseudo-terminal with a simulated Kobuki motor side, in lockstep.

Each tick: the simulated base runs the last command for 20 ms and writes its feedback packet
into the pty; the real driver reads it, the real odometry and localiser update, the real runner
decides, and the real driver writes the command packet, which the simulated base decodes. Only
the motors (and, when a renderer is given, the camera) are simulated.
"""

from __future__ import annotations

import os
import select

from robot_client.apriltag_localiser import DownwardCamera, Localiser, TagLocator
from robot_client.body import RobotBody
from robot_client.floor import Cell, FloorGrid
from robot_client.kobuki import KobukiSerial
from robot_client.odometry import Pose
from robot_client.runner import ActionRunner, GridAction, RunnerEvent
from tests.robot_client.floor_render import FloorRenderer
from tests.robot_client.kobuki_side import SimulatedBase, read_commands

CAMERA = DownwardCamera(width_px=640, height_px=480, ppm=800.0, forward_m=0.25)
TICK_MS = 20.0


class PtyRig:
    """Lockstep simulation of one robot (see module doc)."""

    def __init__(self, floor: FloorGrid, start: Cell, theta: float, *,
                 pose_error: tuple[float, float, float] = (0.0, 0.0, 0.0),
                 renderer: FloorRenderer | None = None, frame_every: int = 10) -> None:
        self.master, self._slave = os.openpty()
        self.base = KobukiSerial(os.ttyname(self._slave))
        x, y = floor.centre(start)
        self.sim = SimulatedBase(x=x, y=y, theta=theta)
        ex, ey, et = pose_error
        localiser = Localiser(TagLocator(floor, CAMERA), Pose(x + ex, y + ey, theta + et))
        self.body = RobotBody(self.base, localiser, ActionRunner(floor))
        self.renderer, self.frame_every = renderer, frame_every
        self.now, self.ticks = 0.0, 0
        self.raw = bytearray()
        self.events: list[RunnerEvent] = []
        self.commands: list[tuple[float, tuple[int, int]]] = []
        self.fixes = 0

    def tick(self) -> None:
        """Advance everything by one control period."""
        self.sim.advance(TICK_MS / 1000.0)
        self.now += TICK_MS
        self.ticks += 1
        os.write(self.master, self.sim.feedback())
        ready, _, _ = select.select([self.base.fileno()], [], [], 1.0)
        assert ready, "feedback packet never reached the driver"
        if self.renderer is not None and self.ticks % self.frame_every == 0:
            frame = self.renderer.view(self.sim.x, self.sim.y, self.sim.theta, noise=5.0, blur=3)
            self.fixes += self.body.on_frame(frame) is not None
        self.events += self.body.tick(self.now)
        (command,) = read_commands(self.master, self.raw, min_count=1)
        self.sim.command = command
        self.commands.append((self.now, command))

    def run(self, action: GridAction, max_ms: float = 20000.0) -> list[RunnerEvent]:
        """Start ``action`` now and tick until the runner finishes it; its events."""
        first = len(self.events)
        self.body.start(action, self.now)
        end = self.now + max_ms
        while self.body.runner.busy:
            assert self.now < end, f"{action} not finished after {max_ms} ms"
            self.tick()
        return self.events[first:]

    def close(self) -> None:
        """Close the driver and the pty."""
        self.base.close()
        os.close(self._slave)
        os.close(self.master)
