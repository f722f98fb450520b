"""Structured logs: one JSON object per line on stderr, rate-limited per message (a storm of
identical records, e.g. ``accept()`` failing while the process is out of file descriptors,
becomes a few lines and a count of the suppressed ones)."""

from __future__ import annotations

import json
import logging
import sys
import time
from typing import Any

_STANDARD = frozenset([*vars(logging.makeLogRecord({})), "message", "asctime"])


class JsonFormatter(logging.Formatter):
    """Formats a record as ``{"ts", "level", "logger", "msg", ...extra fields}``."""

    def format(self, record: logging.LogRecord) -> str:
        """The record as one JSON line."""
        out: dict[str, Any] = {
            "ts": round(record.created, 3),
            "level": record.levelname,
            "logger": record.name,
            "msg": record.getMessage(),
        }
        out.update({k: v for k, v in vars(record).items() if k not in _STANDARD})
        if record.exc_info:  # a traceback for our own records, one line for libraries'
            exc = record.exc_info[1]
            out["exc"] = (self.formatException(record.exc_info)
                          if record.name.startswith("fleetgate") or exc is None
                          else f"{type(exc).__name__}: {exc}")
        return json.dumps(out, default=str)


class RateLimit(logging.Filter):
    """Passes at most ``burst`` records with the same logger and message per ``window_s``;
    the first record of the next window carries ``suppressed`` (how many were dropped)."""

    def __init__(self, burst: int = 10, window_s: float = 10.0) -> None:
        super().__init__()
        self._burst = burst
        self._window = window_s
        self._seen: dict[tuple[str, str], tuple[float, int, int]] = {}

    def filter(self, record: logging.LogRecord) -> bool:
        """True if the record may be written."""
        key = (record.name, str(record.msg))
        now = time.monotonic()
        start, passed, dropped = self._seen.get(key, (now, 0, 0))
        if now - start >= self._window:
            if dropped:
                record.suppressed = dropped
            start, passed, dropped = now, 0, 0
        if passed >= self._burst:
            self._seen[key] = (start, passed, dropped + 1)
            return False
        if len(self._seen) > 10_000:
            self._seen.clear()
        self._seen[key] = (start, passed + 1, dropped)
        return True


def configure_logging(level: str = "INFO") -> None:
    """Send every ``fleetgate.*`` log record (and warnings of ``asyncio`` and ``websockets``)
    to stderr as rate-limited JSON lines."""
    handler = logging.StreamHandler(sys.stderr)
    handler.setFormatter(JsonFormatter())
    handler.addFilter(RateLimit())
    root = logging.getLogger("fleetgate")
    root.handlers[:] = [handler]
    root.setLevel(level)
    root.propagate = False
    for name in ("asyncio", "websockets"):
        other = logging.getLogger(name)
        other.handlers[:] = [handler]
        other.setLevel(max(logging.WARNING, logging.getLevelName(level)))
        other.propagate = False
