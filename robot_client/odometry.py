"""Differential-drive odometry from the Kobuki's 16-bit wheel encoder counters.

Frames: the world frame is the floor's (:mod:`robot_client.floor`: x along the grid's columns,
y towards decreasing rows, z up, so angles grow counter-clockwise seen from above); a pose is
``(x, y, theta)`` in metres and radians with theta the robot's heading from the world x axis.
The robot frame has x forward and y to the robot's left.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

TICK_MODULUS = 1 << 16


@dataclass(frozen=True, slots=True)
class DriveGeometry:
    """Wheel and encoder geometry of a differential-drive base (defaults: Kobuki)."""

    ticks_per_rev: float = 2578.33
    wheel_radius_m: float = 0.035
    wheelbase_m: float = 0.230

    @property
    def metres_per_tick(self) -> float:
        """Distance a wheel travels per encoder tick."""
        return 2.0 * math.pi * self.wheel_radius_m / self.ticks_per_rev


@dataclass(frozen=True, slots=True)
class Pose:
    """A planar pose in the world frame: metres and radians (theta in (-pi, pi])."""

    x: float
    y: float
    theta: float

    def distance_to(self, other: Pose) -> float:
        """Euclidean distance between the two positions."""
        return math.hypot(other.x - self.x, other.y - self.y)


def wrap_angle(a: float) -> float:
    """``a`` wrapped into (-pi, pi]."""
    w = math.remainder(a, 2.0 * math.pi)
    return math.pi if w == -math.pi else w


def check_count(value: int) -> int:
    """``value`` if it is a 16-bit encoder count, else ValueError."""
    if not 0 <= value < TICK_MODULUS:
        raise ValueError(f"encoder value {value} is not a 16-bit count")
    return value


def tick_delta(previous: int, current: int) -> int:
    """Signed change of a 16-bit counter, assuming it moved less than half its range."""
    check_count(previous)
    check_count(current)
    return (current - previous + TICK_MODULUS // 2) % TICK_MODULUS - TICK_MODULUS // 2


def integrate(pose: Pose, d_left: float, d_right: float, wheelbase_m: float) -> Pose:
    """Move ``pose`` by the given wheel travels (metres), along the exact circular arc."""
    d = (d_left + d_right) / 2.0
    dtheta = (d_right - d_left) / wheelbase_m
    if abs(dtheta) < 1e-9:
        dx, dy = d * math.cos(pose.theta), d * math.sin(pose.theta)
    else:
        r = d / dtheta
        end = pose.theta + dtheta
        dx = r * (math.sin(end) - math.sin(pose.theta))
        dy = -r * (math.cos(end) - math.cos(pose.theta))
    return Pose(pose.x + dx, pose.y + dy, wrap_angle(pose.theta + dtheta))


def relative(origin: Pose, pose: Pose) -> Pose:
    """``pose`` expressed in the frame of ``origin`` (the motion from origin to pose)."""
    c, s = math.cos(origin.theta), math.sin(origin.theta)
    dx, dy = pose.x - origin.x, pose.y - origin.y
    return Pose(c * dx + s * dy, -s * dx + c * dy, wrap_angle(pose.theta - origin.theta))


def compose(base: Pose, motion: Pose) -> Pose:
    """Apply ``motion`` (expressed in ``base``'s frame) to ``base``: inverse of :func:`relative`."""
    c, s = math.cos(base.theta), math.sin(base.theta)
    return Pose(base.x + c * motion.x - s * motion.y, base.y + s * motion.x + c * motion.y,
                wrap_angle(base.theta + motion.theta))


class EncoderOdometry:
    """Turns successive raw encoder readings into wheel travels.

    The first reading only sets the reference and yields no travel.
    """

    def __init__(self, geometry: DriveGeometry | None = None) -> None:
        self.geometry = geometry or DriveGeometry()
        self._last: tuple[int, int] | None = None

    def update(self, left_ticks: int, right_ticks: int) -> tuple[float, float]:
        """(left, right) wheel travel in metres since the previous reading."""
        last, self._last = self._last, (check_count(left_ticks), check_count(right_ticks))
        if last is None:
            return 0.0, 0.0
        k = self.geometry.metres_per_tick
        return tick_delta(last[0], left_ticks) * k, tick_delta(last[1], right_ticks) * k


class Odometry:
    """Dead reckoning: a pose advanced by every encoder reading."""

    def __init__(self, start: Pose, geometry: DriveGeometry | None = None) -> None:
        self.encoders = EncoderOdometry(geometry)
        self.pose = start

    def update(self, left_ticks: int, right_ticks: int) -> Pose:
        """Advance by a new encoder reading and return the new pose."""
        d_left, d_right = self.encoders.update(left_ticks, right_ticks)
        self.pose = integrate(self.pose, d_left, d_right, self.encoders.geometry.wheelbase_m)
        return self.pose
