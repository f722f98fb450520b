"""Logs: readable lines (default) or one JSON object per line, on stderr or into a file."""

from __future__ import annotations

import json
import logging
import sys
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


class TextFormatter(logging.Formatter):
    """Formats a record as ``HH:MM:SS WARNING fleetgate.x: message (key=value ...)``."""

    def __init__(self) -> None:
        super().__init__("%(asctime)s %(levelname)s %(name)s: %(message)s", "%H:%M:%S")

    def format(self, record: logging.LogRecord) -> str:
        """The record as one readable line (plus a traceback, if any)."""
        text = super().format(record)
        extra = _extra(record)
        if extra:
            fields = " ".join(f"{k}={v}" for k, v in extra.items())
            head, sep, rest = text.partition("\n")
            text = f"{head} ({fields}){sep}{rest}"
        return text


def configure_logging(level: str = "INFO", fmt: LogFormat = "text", file: Path | None = None,
                      stream: Any = None) -> None:
    """Send every ``fleetgate.*`` log record to ``file`` (appended), else to ``stream``
    (default stderr), as readable lines or JSON lines. Raises OSError if ``file`` cannot be
    opened."""
    handler: logging.Handler
    if file is not None:
        handler = logging.FileHandler(file, encoding="utf-8")
    else:
        out: TextIO = stream if stream is not None else sys.stderr
        handler = logging.StreamHandler(out)
    handler.setFormatter(JsonFormatter() if fmt == "json" else TextFormatter())
    root = logging.getLogger("fleetgate")
    root.handlers[:] = [handler]
    root.setLevel(level)
    root.propagate = False
