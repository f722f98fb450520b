"""Items queued during one turn of the event loop, released together by one callback."""

from __future__ import annotations

import asyncio
from collections.abc import Callable
from typing import Generic, TypeVar

T = TypeVar("T")


class PerTurn(Generic[T]):
    """Collects items and hands them to ``release`` in ONE ``call_soon`` callback per turn of
    the event loop: the first item of a turn schedules it, so the release runs only after the
    task that queued the items yields (the owner task commits the journal before it yields).
    Must be made inside the running loop."""

    def __init__(self, release: Callable[[list[T]], None]) -> None:
        self._release = release
        self._items: list[T] = []
        self._loop = asyncio.get_running_loop()

    def add(self, item: T) -> None:
        """Queue ``item`` for this turn's release."""
        if not self._items:
            self._loop.call_soon(self._flush)
        self._items.append(item)

    def _flush(self) -> None:
        items, self._items = self._items, []
        self._release(items)
