"""Localisation on the AprilTag floor grid, fused with wheel odometry.

Camera model (explicit and deliberately simple): the camera looks straight down at the floor
from a fixed height, so the image is a scaled top view of the floor. ``ppm`` is its scale in
pixels per metre on the floor; the image's top points along the robot's heading, its right to
the robot's right; the principal point (default: the image centre) lies ``forward_m`` in front
of the robot's centre. A pixel ``(u, v)`` is then the floor point, in the robot frame (x forward,
y left)::

    x_r = forward_m + (cy - v) / ppm        y_r = (cx - u) / ppm

Tags are found with OpenCV's ``cv2.aruco.ArucoDetector`` (dictionary DICT_APRILTAG_36h11). The
corners of every grid tag in view give point pairs (robot frame -> world frame, see
:mod:`robot_client.floor`); a 2-D similarity fitted to them (``cv2.estimateAffinePartial2D``) is
the robot's pose: its translation the position, its rotation the heading. A fit whose scale is
far from 1 (miscalibrated ``ppm`` or a misdetection) is refused.

Fusion rule: odometry advances the pose between frames; a tag fix moves the pose towards the
fix by ``tag_gain`` (1.0 = snap to the tag, the default), after replaying on the fix the
odometry motion made since the frame was captured.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np
import numpy.typing as npt

from robot_client.floor import Cell, FloorGrid
from robot_client.odometry import (
    DriveGeometry,
    EncoderOdometry,
    Pose,
    compose,
    integrate,
    relative,
    wrap_angle,
)

Image = npt.NDArray[np.uint8]


@dataclass(frozen=True, slots=True)
class DownwardCamera:
    """The downward-looking camera: image size, scale and mounting offset (see module doc)."""

    width_px: int = 640
    height_px: int = 480
    ppm: float = 800.0
    forward_m: float = 0.25
    cx: float | None = None
    cy: float | None = None

    def to_robot(self, uv: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
        """Pixel coordinates (N x 2, u right, v down) -> floor points in the robot frame."""
        cx = (self.width_px - 1) / 2 if self.cx is None else self.cx
        cy = (self.height_px - 1) / 2 if self.cy is None else self.cy
        return np.column_stack([self.forward_m + (cy - uv[:, 1]) / self.ppm,
                                (cx - uv[:, 0]) / self.ppm])


@dataclass(frozen=True, slots=True)
class TagFix:
    """A pose measured from the tags in one frame."""

    pose: Pose
    cell: Cell
    tag_ids: tuple[int, ...]
    scale: float
    """Scale of the fitted similarity (1.0 when ``ppm`` is exact)."""


class TagLocator:
    """Measures the robot's pose from the grid tags visible in a camera frame."""

    def __init__(self, floor: FloorGrid, camera: DownwardCamera, *,
                 max_scale_error: float = 0.15) -> None:
        self.floor = floor
        self.camera = camera
        self.max_scale_error = max_scale_error
        params = cv2.aruco.DetectorParameters()
        params.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_SUBPIX
        dictionary = cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_APRILTAG_36h11)
        self._detector = cv2.aruco.ArucoDetector(dictionary, params)

    def locate(self, frame: Image) -> TagFix | None:
        """The pose measured in ``frame`` (grey or BGR), or None if no usable grid tag is seen."""
        grey = frame if frame.ndim == 2 else cv2.cvtColor(frame, cv2.COLOR_BGR2GRAY)
        corners, ids, _ = self._detector.detectMarkers(grey)
        if ids is None or len(corners) == 0:
            return None
        robot_pts: list[npt.NDArray[np.float64]] = []
        world_pts: list[list[tuple[float, float]]] = []
        seen: list[int] = []
        for quad, tag_id in zip(corners, np.asarray(ids).reshape(-1).tolist(), strict=True):
            if self.floor.tag_cell(int(tag_id)) is None:
                continue
            robot_pts.append(self.camera.to_robot(np.asarray(quad, np.float64).reshape(4, 2)))
            world_pts.append(self.floor.tag_corners(int(tag_id)))
            seen.append(int(tag_id))
        if not seen:
            return None
        src = np.vstack(robot_pts)
        dst = np.asarray(world_pts, np.float64).reshape(-1, 2)
        m, _ = cv2.estimateAffinePartial2D(src, dst, method=cv2.LMEDS)
        if m is None:
            return None
        scale = math.hypot(m[0, 0], m[1, 0])
        if abs(scale - 1.0) > self.max_scale_error:
            return None
        pose = Pose(float(m[0, 2]), float(m[1, 2]), math.atan2(m[1, 0], m[0, 0]))
        return TagFix(pose, self.floor.cell_at(pose.x, pose.y), tuple(sorted(seen)), scale)


class Localiser:
    """The robot's pose: odometry between frames, corrected by tag fixes."""

    def __init__(self, locator: TagLocator, start: Pose, *,
                 drive: DriveGeometry | None = None, tag_gain: float = 1.0) -> None:
        if not 0.0 < tag_gain <= 1.0:
            raise ValueError(f"tag_gain {tag_gain} must be in (0, 1]")
        self.locator = locator
        self.encoders = EncoderOdometry(drive)
        self.tag_gain = tag_gain
        self.pose = start
        self.last_fix: TagFix | None = None

    @property
    def cell(self) -> Cell:
        """The cell the robot's centre is in."""
        return self.locator.floor.cell_at(self.pose.x, self.pose.y)

    def on_encoders(self, left_ticks: int, right_ticks: int) -> Pose:
        """Advance the pose by a new encoder reading."""
        d_left, d_right = self.encoders.update(left_ticks, right_ticks)
        self.pose = integrate(self.pose, d_left, d_right, self.encoders.geometry.wheelbase_m)
        return self.pose

    def on_frame(self, frame: Image) -> TagFix | None:
        """Measure the pose in ``frame`` and apply it; None (pose unchanged) if no tag."""
        fix = self.locator.locate(frame)
        if fix is not None:
            self.apply(fix)
        return fix

    def apply(self, fix: TagFix, seen_at: Pose | None = None) -> Pose:
        """Move the pose towards a fix by ``tag_gain``.

        ``seen_at`` is the pose estimate when the frame was captured: the odometry motion since
        then is replayed on top of the fix, so a fix that took a while to compute is not stale.
        """
        f = fix.pose if seen_at is None else compose(fix.pose, relative(seen_at, self.pose))
        g, p = self.tag_gain, self.pose
        self.pose = Pose(p.x + g * (f.x - p.x), p.y + g * (f.y - p.y),
                         wrap_angle(p.theta + g * wrap_angle(f.theta - p.theta)))
        self.last_fix = fix
        return self.pose
