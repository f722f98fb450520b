"""Progress on the terminal: one live status line on stderr, with messages printed above it.

On a terminal the status line is rewritten in place (carriage return, erase line); anything
else printed through :meth:`StatusLine.print` (or a log handler writing to
:attr:`StatusLine.stream`) first clears it and then redraws it, so log records and the status
never share a line. On a pipe or file nothing live is written: only the printed lines.
Standard library only, so every command can use it without slowing its start.
"""

from __future__ import annotations

import sys
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import TextIO


class StatusLine:
    """A live one-line status on ``stream`` (stderr); thread-safe."""

    def __init__(self, stream: TextIO | None = None, live: bool | None = None) -> None:
        self._out = stream if stream is not None else sys.stderr
        self.live = self._out.isatty() if live is None else live
        self._text = ""
        self._lock = threading.Lock()
        self.stream = _Above(self)
        """A file-like object: what is written to it is printed above the status line."""

    def set(self, text: str) -> None:
        """Show ``text`` as the status (on a terminal; elsewhere it is only remembered)."""
        with self._lock:
            self._text = text
            if self.live:
                self._out.write("\r\x1b[K" + text)
                self._out.flush()

    def print(self, line: str) -> None:
        """Print ``line`` (a finished message) above the status line."""
        self._write(line if line.endswith("\n") else line + "\n")

    def clear(self) -> None:
        """Remove the status line (the terminal's line is left empty)."""
        with self._lock:
            if self.live and self._text:
                self._out.write("\r\x1b[K")
                self._out.flush()
            self._text = ""

    def _write(self, text: str) -> None:
        with self._lock:
            if self.live and self._text:
                self._out.write("\r\x1b[K")
            self._out.write(text)
            if self.live and self._text:
                self._out.write(self._text)
            self._out.flush()


class _Above:
    """The file-like side of :class:`StatusLine` (for ``logging.StreamHandler``)."""

    def __init__(self, status: StatusLine) -> None:
        self._status = status
        self._pending = ""

    def write(self, text: str) -> int:
        self._pending += text
        if "\n" in self._pending:
            done, _, self._pending = self._pending.rpartition("\n")
            self._status._write(done + "\n")
        return len(text)

    def flush(self) -> None:
        if self._pending:
            pending, self._pending = self._pending, ""
            self._status._write(pending + "\n")

    def isatty(self) -> bool:
        return False


@contextmanager
def ticking(status: StatusLine, label: Callable[[float], str],
            period_s: float = 0.5) -> Iterator[None]:
    """While the block runs, show ``label(elapsed seconds)`` every ``period_s`` (a blocking
    computation such as planning shows that it is alive); the status is cleared afterwards."""
    if not status.live:
        yield
        return
    began = time.monotonic()
    done = threading.Event()

    def tick() -> None:
        while True:
            status.set(label(time.monotonic() - began))
            if done.wait(period_s):
                return

    thread = threading.Thread(target=tick, name="fleetgate-progress", daemon=True)
    thread.start()
    try:
        yield
    finally:
        done.set()
        thread.join()
        status.clear()
