"""A connection as the owner task sees it (:class:`Session`), and the usual kind
(:class:`LinkSession`): one connection's outgoing side, a bounded send queue drained by its own
writer task. (A connection that a worker process serves is a
:class:`~gateway.server.workers.remote.RemoteSession`.)

The owner task never awaits a peer: it builds a message and puts it in the session's queue.
The writers are woken in batches (:func:`wake_writers`, released by a
:class:`~gateway.server.per_turn.PerTurn`): once per turn of the event loop, after
the task that queued the messages yields, not once per message (the owner's messages could not
leave earlier anyway: it commits the journal before it yields); an idle writer's messages are
written by the wake-up itself while the link can take them without waiting (no task switch
per message), the writer task takes what must wait. If that queue is full the
peer is too slow and the session is closed (code 1013), so one slow client never stalls the
others. Also counts the peer's protocol errors (closing the connection
on repeated abuse, code 1008: an error budget of ``max_errors`` that forgets one error every
``error_decay_s``) and rate-limits it (token bucket on the loop clock).
"""

from __future__ import annotations

import asyncio
import itertools
import logging
from abc import ABC, abstractmethod
from collections import deque
from collections.abc import Callable
from typing import Any

from gateway.server.per_turn import PerTurn
from gateway.server.wire.auth import Peer
from gateway.server.wire.transport import Link, LinkClosed
from protocol import (
    PROTOCOL_VERSION,
    AnyMessage,
    Error,
    ErrorCode,
    action_body,
    action_text,
    encode,
)
from protocol.messages import ProtocolVersion

log = logging.getLogger("fleetgate.session")

_ids = itertools.count(1)


def wake_writers(sessions: list[LinkSession]) -> None:
    """Wake the writers of ``sessions`` (released once per loop turn by a :class:`PerTurn`)."""
    for session in sessions:
        session.wake()


class Session(ABC):
    """An authenticated connection as the owner task sees it: who is on it, the protocol
    version it speaks, and what may be sent to it."""

    peer: Peer
    id: int
    closing: bool
    version: ProtocolVersion

    def __str__(self) -> str:
        return f"{self.peer}#{self.id}"

    @abstractmethod
    def send(self, kind: type[AnyMessage], **fields: Any) -> None:
        """Queue a message of type ``kind`` with these fields (dropped once closing)."""

    @abstractmethod
    def send_action(self, fields: dict[str, Any]) -> None:
        """Queue an ``action`` with these fields (plain JSON values, see
        :func:`~protocol.codec.encode_action`), written without building its model."""

    @abstractmethod
    def error(self, code: ErrorCode, ref: str | None, detail: str) -> None:
        """Reply ``error``; too many in a short time close the connection (1008)."""

    @abstractmethod
    def close(self, code: int = 1000, reason: str = "") -> None:
        """Flush what is queued, then close the connection (idempotent)."""


class LinkSession(Session):
    """A session served in this process: its messages go to a :class:`Link`."""

    def __init__(self, link: Link, *, queue_size: int, max_errors: int, rate_per_s: float,
                 rate_burst: float, wakeups: PerTurn[LinkSession], error_decay_s: float = 1.0,
                 on_error: Callable[[ErrorCode], None] | None = None) -> None:
        self.link = link
        self.peer = link.peer
        self.id = next(_ids)
        # the send queue: a deque and the writer's waiter (an asyncio.Queue costs the owner
        # about twice as much per message: its bookkeeping and a wake-up per put)
        self._queue: deque[str | None] = deque()
        self._queue_size = queue_size
        self._waiter: asyncio.Future[None] | None = None  # the idle writer's
        self._wakeups = wakeups
        self._in_wakeups = False  # the writer will be woken at the next turn of the loop
        self._seq = itertools.count()
        self._max_errors = max_errors
        self._error_decay_s = error_decay_s
        self.errors = 0
        """Recent protocol errors (one forgotten per ``error_decay_s``)."""
        self._loop = asyncio.get_running_loop()
        self._errors_at = self._loop.time()
        self._on_error = on_error
        self._rate = rate_per_s
        self._burst = rate_burst
        self._tokens = rate_burst
        self._last = self._loop.time()
        self.closing = False
        self.version = PROTOCOL_VERSION
        """The protocol version of this connection (a robot's ``hello`` fixes it)."""
        self.writer = asyncio.create_task(self._write(), name=f"writer-{self.id}")

    def send(self, kind: type[AnyMessage], **fields: Any) -> None:
        """Build a message of type ``kind`` with this session's next msg_id/seq and queue it
        (nothing if the session is closing; a session too slow to take it is closed)."""
        if self.closing:
            return
        seq = next(self._seq)
        self._put(encode(kind(v=self.version, msg_id=f"g{self.id}-{seq}", seq=seq, **fields)))

    def send_action(self, fields: dict[str, Any]) -> None:
        """Queue an ``action`` with these fields (plain JSON values, see
        :func:`~protocol.codec.encode_action`) and this session's next msg_id/seq, written
        without building its model (the owner's hot path)."""
        if not self.closing:
            self.send_action_body(action_body(fields))

    def send_action_body(self, body: str) -> None:
        """Queue an ``action`` of this JSON body (:func:`~protocol.codec.action_body`: a
        worker process gets the owner's actions so) and this session's next msg_id/seq."""
        if not self.closing:
            seq = next(self._seq)
            self._put(action_text(self.version, f"g{self.id}-{seq}", seq, body))

    def _put(self, text: str) -> bool:
        """Queue ``text`` for the writer; False (and the session closed) if it is too slow."""
        if len(self._queue) >= self._queue_size:
            log.warning("send queue full, closing", extra={"peer": str(self)})
            self.close(1013, "too slow: send queue full")
            return False
        self._queue.append(text)
        if not self._in_wakeups:
            self._in_wakeups = True
            self._wakeups.add(self)
        return True

    def wake(self) -> None:
        """Write what is queued (:func:`wake_writers` calls this, once the owner task
        yielded). If the writer is idle, the link writes each message at once while it can
        without waiting (:meth:`~gateway.server.wire.transport.Link.send_now`: no task switch,
        future or flow-control wait per message); the writer task takes the rest, if any."""
        self._in_wakeups = False
        if self._waiter is None:
            return  # the writer is at work: it will get to the queue
        queue = self._queue
        send_now = self.link.send_now
        while queue:
            text = queue[0]
            if text is None or not send_now(text):
                break
            queue.popleft()
        if queue:
            self._wake_writer()

    def _wake_writer(self) -> None:
        waiter = self._waiter
        if waiter is not None:
            self._waiter = None
            if not waiter.done():
                waiter.set_result(None)

    def error(self, code: ErrorCode, ref: str | None, detail: str) -> None:
        """Reply ``error``; close the connection (1008) after too many in a short time."""
        now = self._loop.time()
        forgiven = int((now - self._errors_at) / self._error_decay_s)
        if forgiven >= self.errors:
            self.errors, self._errors_at = 0, now
        elif forgiven > 0:
            self.errors -= forgiven
            self._errors_at += forgiven * self._error_decay_s
        self.errors += 1
        if self._on_error is not None:
            self._on_error(code)
        self.send(Error, code=code, ref=ref, detail=detail)
        if self.errors >= self._max_errors:
            self.close(1008, f"too many protocol errors ({self._max_errors} recently)")

    def allow(self) -> bool:
        """Take one token of the rate limit; False if the peer sends too fast."""
        now = self._loop.time()
        self._tokens = min(self._burst, self._tokens + (now - self._last) * self._rate)
        self._last = now
        if self._tokens < 1.0:
            return False
        self._tokens -= 1.0
        return True

    def close(self, code: int = 1000, reason: str = "") -> None:
        """Flush what is queued, then close the link."""
        if self.closing:
            return
        self.closing = True
        self._close_args = (code, reason)
        if len(self._queue) >= self._queue_size:
            self.writer.cancel()
            self._closer = self._loop.create_task(self.link.close(code, reason))
        else:  # (the writer, not wake: this may run in the owner task, before its commit)
            self._queue.append(None)
            self._wake_writer()

    async def _write(self) -> None:
        try:
            queue = self._queue
            while True:
                while not queue:
                    self._waiter = self._loop.create_future()
                    await self._waiter
                text = queue.popleft()
                if text is None:
                    await self.link.close(*self._close_args)
                    return
                await self.link.send(text)
        except LinkClosed:
            self.closing = True
