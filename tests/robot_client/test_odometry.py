"""Differential-drive odometry: numbers derived by hand from the Kobuki's geometry."""

from __future__ import annotations

import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from robot_client.odometry import (
    DriveGeometry,
    EncoderOdometry,
    Odometry,
    Pose,
    compose,
    integrate,
    relative,
    tick_delta,
    wrap_angle,
)

# One tick = 2 * pi * 0.035 / 2578.33 = 0.2199115 / 2578.33 = 8.529222e-5 m.
METRES_PER_TICK = 8.529222e-5
B = 0.230


def test_metres_per_tick() -> None:
    assert DriveGeometry().metres_per_tick == pytest.approx(METRES_PER_TICK, rel=1e-6)


def test_tick_delta_handles_16_bit_wraparound() -> None:
    assert tick_delta(65530, 4) == 10
    assert tick_delta(4, 65530) == -10
    assert tick_delta(100, 100) == 0
    assert tick_delta(0, 32767) == 32767
    with pytest.raises(ValueError, match="16-bit"):
        tick_delta(0, 65536)


def test_straight_drive_across_the_wrap() -> None:
    odo = Odometry(Pose(1.0, 2.0, math.pi / 2))
    odo.update(65000, 100)
    # 10000 ticks on each wheel (65000 -> 9464 wraps): 10000 * 8.529222e-5 = 0.8529222 m,
    # straight along the heading (+y).
    pose = odo.update((65000 + 10000) % 65536, 10100)
    assert pose.x == pytest.approx(1.0, abs=1e-9)
    assert pose.y == pytest.approx(2.0 + 0.8529222, abs=1e-6)
    assert pose.theta == pytest.approx(math.pi / 2)


def test_spin_in_place_quarter_turn() -> None:
    odo = Odometry(Pose(0.0, 0.0, 0.0))
    odo.update(5000, 5000)
    # A quarter turn moves each wheel pi/2 * b/2 = 0.180642 m = 2117.9 ticks; with 2118 ticks
    # theta = 2 * 2118 * 8.529222e-5 / 0.230 = 1.5708602 rad.
    pose = odo.update(5000 - 2118, 5000 + 2118)
    assert pose.theta == pytest.approx(1.5708602, abs=1e-6)
    assert (pose.x, pose.y) == pytest.approx((0.0, 0.0), abs=1e-12)


def test_pivot_about_the_left_wheel() -> None:
    # The right wheel drives a quarter circle of radius b around the stopped left wheel, which
    # sits at (0, b/2) for a robot at the origin facing +x. The centre, at (0, -b/2) from the
    # pivot, turns by +90 degrees to (b/2, 0) from it: (0.115, 0.115).
    pose = integrate(Pose(0.0, 0.0, 0.0), 0.0, math.pi / 2 * B, B)
    assert (pose.x, pose.y, pose.theta) == pytest.approx((0.115, 0.115, math.pi / 2), abs=1e-12)


def test_first_reading_sets_the_reference() -> None:
    enc = EncoderOdometry()
    assert enc.update(30000, 40000) == (0.0, 0.0)
    left, right = enc.update(30010, 39990)
    assert (left, right) == pytest.approx((10 * METRES_PER_TICK, -10 * METRES_PER_TICK),
                                          rel=1e-6)
    with pytest.raises(ValueError):
        enc.update(-1, 0)
    # the bad reading did not replace the reference
    assert enc.update(30010, 39990) == (0.0, 0.0)


def test_wrap_angle() -> None:
    assert wrap_angle(3 * math.pi / 2) == pytest.approx(-math.pi / 2)
    assert wrap_angle(-math.pi) == pytest.approx(math.pi)


@settings(max_examples=100, deadline=None)
@given(st.floats(-0.5, 0.5), st.floats(-0.5, 0.5), st.integers(1, 50),
       st.floats(-math.pi, math.pi))
def test_arc_integration_is_additive(d_left: float, d_right: float, n: int,
                                     theta: float) -> None:
    """Constant wheel ratio means one circular arc: n equal steps land where one step does."""
    whole = integrate(Pose(0.3, -0.2, theta), d_left, d_right, B)
    pose = Pose(0.3, -0.2, theta)
    for _ in range(n):
        pose = integrate(pose, d_left / n, d_right / n, B)
    assert (pose.x, pose.y) == pytest.approx((whole.x, whole.y), abs=1e-9)
    assert wrap_angle(pose.theta - whole.theta) == pytest.approx(0.0, abs=1e-9)


def test_relative_and_compose() -> None:
    # Origin at (1, 1) facing N; a pose at (1, 2) facing W is 1 m ahead, turned +90 degrees.
    origin, pose = Pose(1.0, 1.0, math.pi / 2), Pose(1.0, 2.0, math.pi)
    motion = relative(origin, pose)
    assert (motion.x, motion.y, motion.theta) == pytest.approx((1.0, 0.0, math.pi / 2))
    back = compose(origin, motion)
    assert (back.x, back.y, back.theta) == pytest.approx((1.0, 2.0, math.pi))
