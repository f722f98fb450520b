"""One idle deadline per connection, instead of an ``asyncio.timeout()`` around every receive.

A per-message timeout costs a context manager, a timer handle pushed on the loop's heap and
cancelled again for every message a robot sends. :class:`IdleDeadline` keeps ONE timer per
connection: a received message only stores the loop time (:meth:`IdleDeadline.touch`); when
the timer fires it looks at the last message and either re-arms itself for ``last + limit`` or
expires, cancelling the connection's task, whose pending receive then raises
:class:`asyncio.CancelledError` (:meth:`IdleDeadline.consume_expiry` tells that apart from any
other cancellation). So a silent peer is dropped ``limit`` seconds after its last message, as
before, at one timer per ``limit`` seconds of traffic instead of one per message.
"""

from __future__ import annotations

import asyncio


class IdleDeadline:
    """Cancels ``task`` once ``limit`` seconds have passed without a :meth:`touch`."""

    def __init__(self, task: asyncio.Task[object], limit: float) -> None:
        self._loop = task.get_loop()
        self._task = task
        self.limit = limit
        self._last = self._loop.time()
        self.expired = False
        self._handle = self._loop.call_at(self._last + limit, self._check)

    def touch(self) -> None:
        """Something arrived: the deadline moves to ``limit`` seconds from now."""
        self._last = self._loop.time()

    def set_limit(self, limit: float) -> None:
        """Change the allowed silence (e.g. after ``hello``), counted from the last touch."""
        self.limit = limit
        self._handle.cancel()
        self._handle = self._loop.call_at(self._last + limit, self._check)

    def cancel(self) -> None:
        """Stop watching (the connection is ending)."""
        self._handle.cancel()

    def consume_expiry(self) -> bool:
        """Called in the task on :class:`asyncio.CancelledError`: whether it is this deadline's
        doing and nothing else's (then the cancellation is consumed; re-raise it otherwise)."""
        return self.expired and self._task.uncancel() == 0

    def _check(self) -> None:
        due = self._last + self.limit
        if self._loop.time() < due:
            self._handle = self._loop.call_at(due, self._check)
            return
        self.expired = True
        self._task.cancel()
