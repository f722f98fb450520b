"""Items queued during one turn of the event loop, released together by one callback."""

from __future__ import annotations

import asyncio
from collections.abc import Callable
from typing import Generic, TypeVar

T = TypeVar("T")


class PerTurn(Generic[T]):
    """Collects items and hands them to ``release`` in ONE callback per turn of the event
    loop: the first item of a turn schedules it, so the release runs only after the task that
    queued the items yields (the owner task commits the journal before it yields). Must be
    made inside the running loop.

    ``interval_s`` > 0 makes it one release per ``interval_s`` at most: an item added after a
    quiet spell goes at the next turn as before, one added sooner after the last release
    waits until ``interval_s`` after it, with everything else added meanwhile (under a steady
    stream, one release per interval instead of one per turn; nothing waits longer)."""

    def __init__(self, release: Callable[[list[T]], None], interval_s: float = 0.0) -> None:
        self._release = release
        self._items: list[T] = []
        self._loop = asyncio.get_running_loop()
        self._interval_s = interval_s
        self._released_at = -interval_s  # loop time of the last release
        self._due: asyncio.Handle | None = None  # the release scheduled for what is queued

    def add(self, item: T) -> None:
        """Queue ``item`` for this turn's release (or, with an interval, the next one)."""
        if not self._items:
            loop = self._loop
            at = self._released_at + self._interval_s
            if self._interval_s and at > loop.time():
                self._due = loop.call_at(at, self._flush)
            else:
                self._due = loop.call_soon(self._flush)
        self._items.append(item)

    def flush(self) -> None:
        """Release what was added now, not at its turn (the owner task, once it committed
        the journal: one loop turn less a batch)."""
        if self._due is not None:
            self._due.cancel()
            self._flush()

    def _flush(self) -> None:
        if self._interval_s:
            self._released_at = self._loop.time()
        items, self._items, self._due = self._items, [], None
        self._release(items)
