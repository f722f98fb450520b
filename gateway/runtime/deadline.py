"""Wall-clock deadlines for the planner: time lives in the command layer, not in planning."""

from __future__ import annotations

import time


class WallDeadline:
    """Expires ``seconds`` of wall time (``time.monotonic``) after it was created.

    ``seconds=None`` never expires. Satisfies :class:`gateway.planning.plan.Deadline`.
    """

    def __init__(self, seconds: float | None) -> None:
        if seconds is not None and seconds <= 0:
            raise ValueError(f"a time limit must be positive, got {seconds}")
        self.seconds = seconds
        self._start = time.monotonic()

    def elapsed(self) -> float:
        """Seconds since the deadline was created."""
        return time.monotonic() - self._start

    def expired(self) -> bool:
        """True once the time limit has passed."""
        return self.seconds is not None and self.elapsed() >= self.seconds
