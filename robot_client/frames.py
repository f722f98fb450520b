"""Camera frame sources: the only camera-facing interface of the robot client."""

from __future__ import annotations

from typing import Protocol

import cv2
import numpy as np

from robot_client.apriltag_localiser import Image


class FrameSource(Protocol):
    """Something that yields camera frames (blocking; called from a worker thread)."""

    def read(self) -> Image | None:
        """The next frame, or None if none could be captured."""
        ...

    def close(self) -> None:
        """Release the device."""
        ...


class VideoCaptureSource:
    """A camera opened with ``cv2.VideoCapture`` (frames converted to grey)."""

    def __init__(self, index: int, width_px: int, height_px: int) -> None:
        self._cap = cv2.VideoCapture(index)
        if not self._cap.isOpened():
            raise OSError(f"cannot open camera {index}")
        self._cap.set(cv2.CAP_PROP_FRAME_WIDTH, width_px)
        self._cap.set(cv2.CAP_PROP_FRAME_HEIGHT, height_px)
        self._cap.set(cv2.CAP_PROP_BUFFERSIZE, 1)  # latest frame, not a stale queue

    def read(self) -> Image | None:
        """Capture one frame."""
        ok, frame = self._cap.read()
        if not ok or frame is None:
            return None
        return np.asarray(cv2.cvtColor(frame, cv2.COLOR_BGR2GRAY), np.uint8)

    def close(self) -> None:
        """Release the camera."""
        self._cap.release()
