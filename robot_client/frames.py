"""Camera frame sources: the only camera-facing interface of the robot client.

Frames carry their capture time on the robot's clock (:func:`monotonic_ms`), so the localiser
can relate a fix to the pose the robot had when the frame was taken.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Protocol

import cv2
import numpy as np

from robot_client.apriltag_localiser import Image


def monotonic_ms() -> float:
    """The robot client's clock: monotonic milliseconds."""
    return time.monotonic() * 1000.0


@dataclass(frozen=True, slots=True)
class CapturedFrame:
    """A camera image and when it was captured (:func:`monotonic_ms`)."""

    image: Image
    t_ms: float


class FrameSource(Protocol):
    """Something that yields camera frames (blocking; called from a worker thread)."""

    def read(self) -> CapturedFrame | None:
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

    def read(self) -> CapturedFrame | None:
        """Capture one frame; its time is taken when the driver hands it over (grab)."""
        if not self._cap.grab():
            return None
        t_ms = monotonic_ms()
        ok, frame = self._cap.retrieve()
        if not ok or frame is None:
            return None
        return CapturedFrame(np.asarray(cv2.cvtColor(frame, cv2.COLOR_BGR2GRAY), np.uint8), t_ms)

    def close(self) -> None:
        """Release the camera."""
        self._cap.release()
