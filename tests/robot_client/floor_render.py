"""Synthetic camera frames of the AprilTag floor, rendered with OpenCV for the tests.

The floor is drawn as a top view (north up) at ``FLOOR_PPM`` pixels per metre with one
generated 36h11 marker per cell; a camera frame is the warp of that bitmap seen from a robot
pose through the downward camera (image top = robot forward, principal point ``forward_m``
ahead of the robot, ``ppm`` pixels per metre). The geometry is written out here on its own
rather than taken from the localiser.
"""

from __future__ import annotations

import math

import cv2
import numpy as np
import numpy.typing as npt

FLOOR_PPM = 1000.0
MARGIN_M = 0.5


class FloorRenderer:
    """Top-view bitmap of a ``width`` x ``height`` tag grid and camera views of it."""

    def __init__(self, width: int, height: int, cell_m: float, tag_m: float,
                 extra_tags: dict[tuple[float, float], int] | None = None) -> None:
        self.cell_m = cell_m
        # World bounds: x in [x0, x1], y in [y0, y1] (y up = north = decreasing rows).
        self.x0 = -cell_m / 2 - MARGIN_M
        self.y1 = cell_m / 2 + MARGIN_M
        x1 = (width - 0.5) * cell_m + MARGIN_M
        y0 = -(height - 0.5) * cell_m - MARGIN_M
        size = (round((self.y1 - y0) * FLOOR_PPM), round((x1 - self.x0) * FLOOR_PPM))
        self.bitmap = np.full(size, 255, np.uint8)
        dictionary = cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_APRILTAG_36h11)
        side = round(tag_m * FLOOR_PPM)
        placed = {(col * cell_m, -row * cell_m): row * width + col
                  for row in range(height) for col in range(width)}
        placed.update(extra_tags or {})
        for (x, y), tag_id in placed.items():
            marker = cv2.aruco.generateImageMarker(dictionary, tag_id, side, borderBits=1)
            u, v = self.floor_px(x, y)
            top, left = round(v - (side - 1) / 2), round(u - (side - 1) / 2)
            self.bitmap[top : top + side, left : left + side] = marker

    def floor_px(self, x: float, y: float) -> tuple[float, float]:
        """Bitmap pixel (u, v) of world point (x, y)."""
        return (x - self.x0) * FLOOR_PPM, (self.y1 - y) * FLOOR_PPM

    def view(self, x: float, y: float, theta: float, *, ppm: float = 800.0,
             forward_m: float = 0.25, size: tuple[int, int] = (640, 480),
             noise: float = 0.0, blur: int = 0, seed: int = 0) -> npt.NDArray[np.uint8]:
        """The camera frame of a robot at (x, y) heading ``theta`` (grey, uint8)."""
        w, h = size
        cx, cy = (w - 1) / 2, (h - 1) / 2
        c, s = math.cos(theta), math.sin(theta)
        # camera px (u, v) -> robot (f, l) = (forward + (cy - v)/ppm, (cx - u)/ppm)
        # -> world X = x + f c - l s, Y = y + f s + l c -> floor px ((X - x0) P, (y1 - Y) P).
        # Every step is affine in (u, v); compose the 3x3 matrices.
        cam_to_robot = np.array([[0, -1 / ppm, forward_m + cy / ppm],
                                 [-1 / ppm, 0, cx / ppm], [0, 0, 1]])
        robot_to_world = np.array([[c, -s, x], [s, c, y], [0, 0, 1]])
        world_to_floor = np.array([[FLOOR_PPM, 0, -self.x0 * FLOOR_PPM],
                                   [0, -FLOOR_PPM, self.y1 * FLOOR_PPM], [0, 0, 1]])
        m = (world_to_floor @ robot_to_world @ cam_to_robot)[:2]
        img = cv2.warpAffine(self.bitmap, m, (w, h), flags=cv2.INTER_AREA | cv2.WARP_INVERSE_MAP,
                             borderValue=255)
        if blur:
            img = cv2.GaussianBlur(img, (blur, blur), 0)
        if noise:
            rng = np.random.default_rng(seed)
            img = np.clip(img + rng.normal(0, noise, img.shape), 0, 255).astype(np.uint8)
        return np.asarray(img, np.uint8)
