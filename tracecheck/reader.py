"""Reading JSON-lines traces: the checker's own reader, independent of the code that writes them."""

from __future__ import annotations

import json
from collections.abc import Iterator
from pathlib import Path
from typing import Any

Record = dict[str, Any]


def iter_trace(path: str | Path) -> Iterator[Record]:
    """The records of a JSON-lines trace file; ValueError names the line of a bad one."""
    with open(path, encoding="utf-8") as f:
        for lineno, line in enumerate(f, 1):
            if not line.strip():
                continue
            try:
                record = json.loads(line)
            except json.JSONDecodeError as exc:
                raise ValueError(f"{path}:{lineno}: not JSON: {exc.msg}") from None
            if not isinstance(record, dict):
                raise ValueError(f"{path}:{lineno}: a trace line must be a JSON object")
            yield record


def read_trace(path: str | Path) -> list[Record]:
    """All records of a JSON-lines trace file."""
    return list(iter_trace(path))
