"""Writing execution traces as JSON lines (DESIGN section 3).

The records themselves are built by :mod:`gateway.execution.trace_records`; :class:`JsonlWriter`
is the sink that writes them to a file.
"""

from __future__ import annotations

import json
from pathlib import Path
from types import TracebackType
from typing import IO

from gateway.execution.trace_records import Record


class JsonlWriter:
    """A trace sink writing one compact JSON object per line to ``path`` (or an open file)."""

    def __init__(self, target: str | Path | IO[str]) -> None:
        if isinstance(target, (str, Path)):
            self._file: IO[str] = open(target, "w", encoding="utf-8")  # noqa: SIM115
            self._owned = True
        else:
            self._file = target
            self._owned = False

    def __call__(self, record: Record) -> None:
        """Append one record."""
        self._file.write(json.dumps(record, separators=(",", ":")))
        self._file.write("\n")

    def close(self) -> None:
        """Flush, and close the file if this writer opened it."""
        if self._owned:
            self._file.close()
        else:
            self._file.flush()

    def __enter__(self) -> JsonlWriter:
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        self.close()
