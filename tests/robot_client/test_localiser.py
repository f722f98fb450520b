"""AprilTag localisation on real OpenCV-rendered camera frames of the tag floor."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from robot_client.apriltag_localiser import DownwardCamera, Localiser, TagLocator
from robot_client.floor import FloorGrid, heading_of_step, nearest_heading
from robot_client.odometry import Pose, wrap_angle
from tests.robot_client.floor_render import FloorRenderer

GRID = FloorGrid(width=5, height=4, cell_m=0.4, tag_size_m=0.12)
CAMERA = DownwardCamera(width_px=640, height_px=480, ppm=800.0, forward_m=0.25)


@pytest.fixture(scope="module")
def floor() -> FloorRenderer:
    # Tag 400 (not a grid id) lies between cells (0, 3) and (1, 3); it must be ignored.
    return FloorRenderer(5, 4, 0.4, 0.12, extra_tags={(0.2, -1.35): 400})


@pytest.fixture(scope="module")
def locator() -> TagLocator:
    return TagLocator(GRID, CAMERA)


def test_floor_grid_ids_cells_and_headings() -> None:
    assert GRID.tag_id((3, 2)) == 13 and GRID.tag_cell(13) == (3, 2)
    assert GRID.tag_cell(20) is None and GRID.tag_cell(-1) is None
    assert GRID.centre((3, 2)) == pytest.approx((1.2, -0.8))
    assert GRID.cell_at(1.31, -0.61) == (3, 2)
    assert heading_of_step((2, 2), (2, 1)) == "N" and heading_of_step((2, 2), (1, 2)) == "W"
    assert nearest_heading(-1.4) == "S" and nearest_heading(3.0) == "W"
    with pytest.raises(ValueError, match="4-neighbour"):
        heading_of_step((0, 0), (1, 1))
    with pytest.raises(ValueError, match="outside"):
        GRID.tag_id((5, 0))


@pytest.mark.parametrize(("x", "y", "theta", "cell"), [
    (0.8, -0.4, 0.0, (2, 1)),            # on a cell centre, heading E
    (0.85, -0.43, 0.3, (2, 1)),          # off centre, turned
    (0.4, -0.8, math.pi / 2, (1, 2)),    # heading N
    (1.28, -0.35, -2.5, (3, 1)),
    (0.9, -0.7, math.pi, (2, 2)),        # heading W
    (0.03, -1.18, math.pi / 2, (0, 3)),  # corner cell looking into the grid
])
def test_recovers_cell_position_and_heading_under_noise_and_blur(
        floor: FloorRenderer, locator: TagLocator, x: float, y: float, theta: float,
        cell: tuple[int, int]) -> None:
    frame = floor.view(x, y, theta, noise=10.0, blur=3, seed=7)
    fix = locator.locate(frame)
    assert fix is not None
    assert fix.cell == cell
    assert math.hypot(fix.pose.x - x, fix.pose.y - y) < 0.01
    assert abs(math.degrees(wrap_angle(fix.pose.theta - theta))) < 1.0
    assert 400 not in fix.tag_ids


def test_tolerates_mild_perspective_from_a_slightly_tilted_camera(
        floor: FloorRenderer, locator: TagLocator) -> None:
    frame = floor.view(0.82, -0.41, 0.2, blur=3)
    src = np.array([[0, 0], [639, 0], [639, 479], [0, 479]], np.float32)
    dst = np.array([[6, 4], [633, -3], [641, 483], [-4, 475]], np.float32)
    tilted = np.asarray(cv2.warpPerspective(frame, cv2.getPerspectiveTransform(src, dst),
                                            (640, 480), borderValue=255), np.uint8)
    fix = locator.locate(tilted)
    assert fix is not None and fix.cell == (2, 1)
    assert math.hypot(fix.pose.x - 0.82, fix.pose.y + 0.41) < 0.03
    assert abs(math.degrees(wrap_angle(fix.pose.theta - 0.2))) < 3.0


def test_no_tag_in_view_gives_no_fix_and_odometry_only(
        floor: FloorRenderer, locator: TagLocator) -> None:
    # Far outside the grid looking away from it: only the white floor margin is in view.
    frame = floor.view(-0.6, 0.5, math.pi)
    assert locator.locate(frame) is None
    loc = Localiser(locator, Pose(0.0, 0.0, 0.0))
    loc.on_encoders(1000, 1000)
    # 1000 ticks * 8.529222e-5 m = 0.08529 m straight ahead.
    pose = loc.on_encoders(2000, 2000)
    assert loc.on_frame(frame) is None
    assert loc.pose == pose
    assert pose.x == pytest.approx(0.0852922, abs=1e-6)


def test_foreign_tags_alone_are_ignored(floor: FloorRenderer, locator: TagLocator) -> None:
    # In the corner cell (0, 3) facing S, the camera sees the margin south of the grid: tag 400
    # complete, grid tags only cut by the image edge.
    frame = floor.view(0.0, -1.2, -math.pi / 2)
    dictionary = cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_APRILTAG_36h11)
    _, ids, _ = cv2.aruco.ArucoDetector(dictionary).detectMarkers(frame)
    assert ids is not None and np.asarray(ids).reshape(-1).tolist() == [400]
    assert locator.locate(frame) is None


def test_miscalibrated_scale_is_refused(floor: FloorRenderer) -> None:
    frame = floor.view(0.8, -0.4, 0.0, ppm=800.0)
    wrong = TagLocator(GRID, DownwardCamera(ppm=560.0))  # 30 % off
    assert wrong.locate(frame) is None


def test_fix_snaps_or_blends_the_odometry_pose(
        floor: FloorRenderer, locator: TagLocator) -> None:
    frame = floor.view(0.8, -0.4, 0.1)
    snap = Localiser(locator, Pose(0.7, -0.45, -0.1))
    fix = snap.on_frame(frame)
    assert fix is not None and snap.pose == fix.pose and snap.cell == (2, 1)
    half = Localiser(locator, Pose(0.7, -0.45, -0.1), tag_gain=0.5)
    half.apply(fix)
    assert (half.pose.x, half.pose.y, half.pose.theta) == pytest.approx(
        ((0.7 + fix.pose.x) / 2, (-0.45 + fix.pose.y) / 2, (-0.1 + fix.pose.theta) / 2))
    with pytest.raises(ValueError, match="tag_gain"):
        Localiser(locator, Pose(0, 0, 0), tag_gain=0.0)


@settings(max_examples=12, deadline=None)
@given(st.integers(0, 4), st.integers(0, 3), st.floats(-0.12, 0.12), st.floats(-0.12, 0.12),
       st.floats(-math.pi, math.pi))
def test_random_poses_on_the_grid(floor: FloorRenderer, locator: TagLocator, col: int, row: int,
                                  dx: float, dy: float, theta: float) -> None:
    x, y = GRID.centre((col, row))
    frame = floor.view(x + dx, y + dy, theta, noise=6.0, blur=3)
    fix = locator.locate(frame)
    if fix is None:
        # Only possible when every tag in view is outside the grid or cut by the image edge:
        # the view must then contain no complete grid tag (checked by rendering without noise).
        assert locator.locate(floor.view(x + dx, y + dy, theta)) is None
        return
    assert fix.cell == (col, row)
    assert math.hypot(fix.pose.x - x - dx, fix.pose.y - y - dy) < 0.01
    assert abs(math.degrees(wrap_angle(fix.pose.theta - theta))) < 1.0


def test_fix_replays_the_motion_made_since_capture(
        floor: FloorRenderer, locator: TagLocator) -> None:
    fix = locator.locate(floor.view(0.8, -0.4, 0.0))
    assert fix is not None
    loc = Localiser(locator, Pose(0.75, -0.4, 0.0))
    seen_at = loc.pose
    loc.on_encoders(0, 0)
    loc.on_encoders(1000, 1000)  # 0.0852922 m forward while the frame was being processed
    loc.apply(fix, seen_at=seen_at)
    assert loc.pose.x == pytest.approx(fix.pose.x + 0.0852922, abs=1e-4)
    assert loc.pose.y == pytest.approx(fix.pose.y, abs=1e-4)
