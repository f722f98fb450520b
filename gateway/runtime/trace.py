"""Writing execution traces as JSON lines (DESIGN section 3).

The records themselves are built by :mod:`gateway.execution.trace_records`; :class:`JsonlWriter`
is the sink that writes them to a file.
"""

from __future__ import annotations

from contextlib import AbstractContextManager
from pathlib import Path
from types import TracebackType
from typing import IO

import orjson

from fleetgate.userio.files import atomic_open
from gateway.execution.trace_records import Record


def _plain(value: object) -> object:
    """A value orjson does not write itself: a subclass of float or int (numpy's) as one."""
    if isinstance(value, float):
        return float(value)
    if isinstance(value, int):
        return int(value)
    raise TypeError(f"{type(value).__name__} is not JSON serializable")


def trace_line(record: Record) -> str:
    """One trace record as its line: compact JSON (orjson: ~10x cheaper than ``json.dumps``,
    one of several records per action on the gateway's owner task) and a newline. Every
    writer of trace files (the gateway's live and replayed traces, :class:`JsonlWriter`)
    writes this."""
    return orjson.dumps(record, default=_plain).decode() + "\n"


class JsonlWriter:
    """A trace sink writing one compact JSON object per line to ``path`` (or an open file).

    A path is written atomically: the trace appears there whole when the writer is closed
    without an exception, and an interrupted run leaves a previous file as it was
    (:func:`fleetgate.userio.files.atomic_open`; CannotWrite, one line, if it cannot be).
    """

    def __init__(self, target: str | Path | IO[str]) -> None:
        self._owned: AbstractContextManager[IO[str]] | None = None
        if isinstance(target, (str, Path)):
            self._owned = atomic_open(target, what="the trace")
            self._file: IO[str] = self._owned.__enter__()
        else:
            self._file = target

    def __call__(self, record: Record) -> None:
        """Append one record."""
        self._file.write(trace_line(record))

    def close(self, failed: BaseException | None = None) -> None:
        """Flush, and if this writer opened the file put it in place (or, after ``failed``,
        leave the previous one)."""
        if self._owned is None:
            self._file.flush()
            return
        owned, self._owned = self._owned, None
        if failed is None:
            owned.__exit__(None, None, None)
        else:
            owned.__exit__(type(failed), failed, failed.__traceback__)

    def __enter__(self) -> JsonlWriter:
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        self.close(exc)
