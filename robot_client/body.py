"""The robot's body: Kobuki base, localiser and action runner glued into one control tick.

No clock and no event loop here: the caller passes the time and calls :meth:`RobotBody.tick`
every control period (20 ms, the rate the base streams its feedback at) and
:meth:`RobotBody.on_frame` for every camera frame.
"""

from __future__ import annotations

from collections import deque

from robot_client.apriltag_localiser import Image, Localiser, TagFix
from robot_client.kobuki import KobukiSerial
from robot_client.odometry import Pose
from robot_client.runner import ActionRunner, GridAction, RunnerEvent


class RobotBody:
    """Reads the base, updates the pose, runs the current action, commands the wheels."""

    def __init__(self, base: KobukiSerial, localiser: Localiser, runner: ActionRunner, *,
                 history: int = 250) -> None:
        self.base = base
        self.localiser = localiser
        self.runner = runner
        self.bumper = False
        self._history: deque[tuple[float, Pose]] = deque(maxlen=history)

    @property
    def pose(self) -> Pose:
        """The current pose estimate."""
        return self.localiser.pose

    def start(self, action: GridAction, now_ms: float) -> None:
        """Begin executing ``action`` (ValueError if it cannot: see ``ActionRunner.start``)."""
        self.runner.start(action, now_ms, self.localiser.pose)

    def tick(self, now_ms: float) -> list[RunnerEvent]:
        """One control period: feedback in, wheel command out; the runner's new events."""
        for data in self.base.poll():
            self.localiser.on_encoders(data.left_encoder, data.right_encoder)
            self.bumper = data.bumped
        self._history.append((now_ms, self.localiser.pose))
        self.base.drive(*self.runner.step(now_ms, self.localiser.pose, self.bumper))
        return self.runner.drain()

    def pose_at(self, t_ms: float) -> Pose:
        """The pose estimate of the last tick at or before ``t_ms`` (the oldest one kept if
        ``t_ms`` is older; the current pose before the first tick)."""
        for t, pose in reversed(self._history):
            if t <= t_ms:
                return pose
        return self._history[0][1] if self._history else self.localiser.pose

    def on_frame(self, frame: Image) -> TagFix | None:
        """Correct the pose with a camera frame."""
        return self.localiser.on_frame(frame)

    def stop(self) -> None:
        """Stop the wheels now (the current action, if any, stays where it is)."""
        self.base.stop()
