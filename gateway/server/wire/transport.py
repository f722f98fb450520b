"""Transports: how messages reach the gateway. A :class:`Link` is the gateway's end of one
authenticated connection; the websocket transport and the in-memory one both provide it.

The in-memory client (:class:`MemoryClient`) mimics the websockets client connection
(``send``, ``recv``, ``close``, ``async for``, raising ``websockets.ConnectionClosed``), so a
simulated robot can run unchanged over either transport.
"""

from __future__ import annotations

import asyncio
from collections.abc import AsyncIterator
from typing import Protocol

from websockets.asyncio.server import ServerConnection, broadcast
from websockets.exceptions import ConnectionClosed, ConnectionClosedError, ConnectionClosedOK
from websockets.frames import Close
from websockets.protocol import State as WsState

from gateway.server.wire.auth import Peer

HARD_MAX_BYTES = 256 * 1024
"""Frames above this many bytes close the connection (1009); up to it, a message over
``MAX_MESSAGE_BYTES`` gets an error reply (``too_large``)."""


class LinkClosed(Exception):
    """The connection is gone."""


class Link(Protocol):
    """The gateway's end of one connection."""

    peer: Peer

    async def recv(self) -> str | bytes:
        """Next message; LinkClosed when the peer is gone."""
        ...

    async def send(self, text: str) -> None:
        """Send one message; LinkClosed when the peer is gone."""
        ...

    def send_now(self, text: str) -> bool:
        """Send one message at once if that needs no waiting; False: nothing was sent (use
        :meth:`send`)."""
        ...

    async def close(self, code: int = 1000, reason: str = "") -> None:
        """Close the connection (idempotent)."""
        ...


class _Closed:
    """End-of-stream marker carrying the close code."""

    def __init__(self, code: int, reason: str) -> None:
        self.code = code
        self.reason = reason


def _closed_error(code: int, reason: str) -> ConnectionClosed:
    frame = Close(code, reason)
    kind = ConnectionClosedOK if code in (1000, 1001) else ConnectionClosedError
    return kind(frame, frame, rcvd_then_sent=True)


class _Pipe:
    """Two queues between a memory client and its gateway link. Towards the client it is
    bounded (a client that does not read blocks the gateway's writer for it, as a full TCP
    buffer would); towards the gateway it is not (the gateway reads at once and rate-limits),
    so a client never blocks on a gateway that stopped reading."""

    def __init__(self, size: int) -> None:
        self.to_gateway: asyncio.Queue[str | bytes | _Closed] = asyncio.Queue()
        self.to_client: asyncio.Queue[str | _Closed] = asyncio.Queue(size)
        self.closed: _Closed | None = None

    def shut(self, code: int, reason: str) -> None:
        if self.closed is None:
            self.closed = _Closed(code, reason)
            for q in (self.to_gateway, self.to_client):
                _force_put(q, self.closed)


def _force_put(q: asyncio.Queue[str | bytes | _Closed] | asyncio.Queue[str | _Closed],
               item: _Closed) -> None:
    while True:
        try:
            q.put_nowait(item)
            return
        except asyncio.QueueFull:
            q.get_nowait()


class MemoryLink:
    """Gateway end of an in-memory connection."""

    def __init__(self, pipe: _Pipe, peer: Peer) -> None:
        self._pipe = pipe
        self.peer = peer

    async def recv(self) -> str | bytes:
        """Next message from the client."""
        item = await self._pipe.to_gateway.get()
        if isinstance(item, _Closed):
            raise LinkClosed(item.reason)
        return item

    def send_now(self, text: str) -> bool:
        """Never at once: the in-memory link always goes through :meth:`send`."""
        return False

    async def send(self, text: str) -> None:
        """Queue a message for the client (waits while its queue is full)."""
        if self._pipe.closed is not None:
            raise LinkClosed(self._pipe.closed.reason)
        await self._pipe.to_client.put(text)

    async def close(self, code: int = 1000, reason: str = "") -> None:
        """Close both directions."""
        self._pipe.shut(code, reason)


class MemoryClient:
    """Client end of an in-memory connection, shaped like a websockets client connection."""

    def __init__(self, pipe: _Pipe) -> None:
        self._pipe = pipe

    @property
    def close_code(self) -> int | None:
        """The close code once closed (as websockets' ``close_code``)."""
        return self._pipe.closed.code if self._pipe.closed else None

    async def send(self, message: str | bytes) -> None:
        """Send a message; a frame over HARD_MAX_BYTES closes the connection (1009)."""
        if self._pipe.closed is not None:
            raise _closed_error(self._pipe.closed.code, self._pipe.closed.reason)
        size = len(message.encode("utf-8", "surrogatepass") if isinstance(message, str)
                   else message)
        if size > HARD_MAX_BYTES:
            self._pipe.shut(1009, "message too big")
            raise _closed_error(1009, "message too big")
        await self._pipe.to_gateway.put(message)

    async def recv(self) -> str:
        """Next message from the gateway; ConnectionClosed once closed and drained."""
        item = await self._pipe.to_client.get()
        if isinstance(item, _Closed):
            _force_put(self._pipe.to_client, item)  # keep raising on later calls
            raise _closed_error(item.code, item.reason)
        return item

    async def close(self, code: int = 1000, reason: str = "") -> None:
        """Close the connection."""
        self._pipe.shut(code, reason)

    async def __aiter__(self) -> AsyncIterator[str]:
        """Messages until the connection closes normally."""
        try:
            while True:
                yield await self.recv()
        except ConnectionClosedOK:
            return


def memory_pair(peer: Peer, size: int = 4096) -> tuple[MemoryClient, MemoryLink]:
    """A connected in-memory client and gateway link."""
    pipe = _Pipe(size)
    return MemoryClient(pipe), MemoryLink(pipe, peer)


class WebSocketLink:
    """Gateway end of a websocket connection (``websockets.asyncio.server``)."""

    def __init__(self, connection: ServerConnection, peer: Peer) -> None:
        self._conn = connection
        self.peer = peer

    async def recv(self) -> str | bytes:
        """Next message from the peer."""
        try:
            return await self._conn.recv()
        except ConnectionClosed as exc:
            raise LinkClosed(str(exc)) from None

    def send_now(self, text: str) -> bool:
        """Write one message at once if the connection is open and its socket's write buffer
        is within its high-water mark (what :meth:`send` would do without waiting; written
        with websockets' ``broadcast``, its public unawaited send); False otherwise."""
        conn = self._conn
        transport = conn.transport
        if (conn.protocol.state is not WsState.OPEN
                or transport.get_write_buffer_size() > transport.get_write_buffer_limits()[1]):
            return False
        broadcast((conn,), text)
        return True

    async def send(self, text: str) -> None:
        """Send one message (waits while the socket's write buffer is full)."""
        try:
            await self._conn.send(text)
        except ConnectionClosed as exc:
            raise LinkClosed(str(exc)) from None

    async def close(self, code: int = 1000, reason: str = "") -> None:
        """Close the websocket."""
        await self._conn.close(code, reason)
