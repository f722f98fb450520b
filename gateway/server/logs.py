"""Logs: readable lines (default) or one JSON object per line, on stderr or into a file;
rate-limited per message (a storm of identical records, e.g. ``accept()`` failing while the
process is out of file descriptors, becomes a few lines and a count of the suppressed ones),
and one line per record from libraries (asyncio, websockets), without their tracebacks."""

from __future__ import annotations

import json
import logging
import sys
import time
from pathlib import Path
from typing import Any, Literal, TextIO

_STANDARD = frozenset([*vars(logging.makeLogRecord({})), "message", "asctime"])

LogFormat = Literal["text", "json"]


def _extra(record: logging.LogRecord) -> dict[str, Any]:
    return {k: v for k, v in vars(record).items() if k not in _STANDARD}


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
        out.update(_extra(record))
        if record.exc_info:
            out["exc"] = self.formatException(record.exc_info)
        return json.dumps(out, default=str)


_CONTROL = {c: f"\\x{c:02x}" for c in [*range(32), 127]}


def escape(text: str) -> str:
    """``text`` with every control character (line feeds too) written as ``\\xNN``: bytes
    a stranger sent cannot start a line of their own in the log."""
    return text.translate(_CONTROL)


class TextFormatter(logging.Formatter):
    """Formats a record as ``HH:MM:SS WARNING fleetgate.x: message (key=value ...)``; the
    message and the fields are escaped (:func:`escape`), a traceback is not."""

    def __init__(self) -> None:
        super().__init__("%(asctime)s %(levelname)s %(name)s: %(message)s", "%H:%M:%S")

    def format(self, record: logging.LogRecord) -> str:
        """The record as one readable line (plus a traceback, if any)."""
        saved = record.msg, record.args
        record.msg, record.args = escape(record.getMessage()), ()
        try:
            text = super().format(record)
        finally:
            record.msg, record.args = saved
        extra = _extra(record)
        if extra:
            fields = " ".join(f"{k}={escape(str(v))}" for k, v in extra.items())
            head, sep, rest = text.partition("\n")
            text = f"{head} ({fields}){sep}{rest}"
        return text


class RateLimit(logging.Filter):
    """Passes at most ``burst`` records with the same logger and message start per
    ``window_s``; the first record of the next window carries ``suppressed`` (how many were
    dropped). Messages are compared on their first ``KEY_CHARS`` characters: a library's
    record embeds object reprs (asyncio's retry callbacks differ only in their timer handle)."""

    KEY_CHARS = 64

    def __init__(self, burst: int = 10, window_s: float = 10.0) -> None:
        super().__init__()
        self._burst = burst
        self._window = window_s
        self._seen: dict[tuple[str, str], tuple[float, int, int]] = {}

    def filter(self, record: logging.LogRecord) -> bool:
        """True if the record may be written."""
        key = (record.name, str(record.msg)[:self.KEY_CHARS])
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


class LibraryOneLine(logging.Filter):
    """Makes a library's record (asyncio, websockets) one line, its exception folded into the
    message: ``"...: OSError: [Errno 24] Too many open files"`` instead of a traceback."""

    def filter(self, record: logging.LogRecord) -> bool:
        """Always True (the record is changed in place)."""
        if record.name.startswith("fleetgate"):
            return True
        text = " ".join(record.getMessage().split())
        if record.exc_info:
            exc = record.exc_info[1]
            text = f"{text}: {type(exc).__name__}: {exc}"
            record.exc_info = None
            record.exc_text = None
        record.msg, record.args = text, ()
        return True


def configure_logging(level: str = "INFO", fmt: LogFormat = "text", file: Path | None = None,
                      stream: Any = None) -> None:
    """Send every ``fleetgate.*`` log record (and warnings of ``asyncio``, ``websockets`` and
    ``uvicorn``)
    to ``file`` (appended), else to ``stream`` (default stderr), as readable lines or JSON
    lines, rate-limited. Raises OSError if ``file`` cannot be opened."""
    handler: logging.Handler
    if file is not None:
        handler = logging.FileHandler(file, encoding="utf-8")
    else:
        out: TextIO = stream if stream is not None else sys.stderr
        handler = logging.StreamHandler(out)
    handler.setFormatter(JsonFormatter() if fmt == "json" else TextFormatter())
    handler.addFilter(RateLimit())
    handler.addFilter(LibraryOneLine())
    root = logging.getLogger("fleetgate")
    root.handlers[:] = [handler]
    root.setLevel(level)
    root.propagate = False
    for name in ("asyncio", "websockets", "uvicorn"):
        other = logging.getLogger(name)
        other.handlers[:] = [handler]
        other.setLevel(max(logging.WARNING, logging.getLevelName(level)))
        other.propagate = False
