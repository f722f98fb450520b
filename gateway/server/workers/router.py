"""A worker's first look at a new connection: a robot's websocket upgrade is served in the
worker, anything else is relayed byte for byte to the owner's HTTP server.

:class:`Router` reads the first request's head (within the handshake timeout, at most
:data:`~gateway.server.wire.asgi_server.MAX_HEAD_BYTES`). If it is a ``GET`` with ``Upgrade:
websocket`` whose credentials are a robot's, the connection goes to the worker's websocket
endpoint with the head as its first bytes (as uvicorn hands an upgrade over); every check of
the handshake then runs there as in the one-process gateway. Anything else (plain HTTP, the
GUI, operators, the world, bad or refused requests) is relayed whole to the owner's unix
socket by two :class:`Pump` s, so the owner answers it exactly as it would on its own port.
"""

from __future__ import annotations

import asyncio
from collections.abc import Callable
from typing import Any

from websockets.datastructures import Headers

from gateway.server.wire.asgi_server import MAX_HEAD_BYTES
from gateway.server.wire.auth import Authenticator, AuthError


def robot_upgrade(head: bytes, auth: Authenticator, cert: dict[str, Any] | None) -> bool:
    """Whether a request head (up to its blank line) is a websocket upgrade with a robot's
    credentials. Anything unusual is not (the owner then answers it)."""
    try:
        line, *fields = head.decode("latin-1").split("\r\n")
        method, path, _version = line.split(" ")
        headers = Headers()
        for field in fields:
            name, sep, value = field.partition(":")
            if not sep:
                return False
            headers[name.strip()] = value.strip()
        upgrade = headers.get_all("Upgrade")
        if method != "GET" or [u.lower() for u in upgrade] != ["websocket"]:
            return False
        return auth.handshake(headers, path, cert).role == "robot"
    except (ValueError, AuthError):
        return False


class Pump(asyncio.Protocol):
    """One direction of a relay: what arrives is written to ``peer``; back-pressure and the
    end of either side carry over."""

    def __init__(self, peer: asyncio.Transport) -> None:
        self._peer = peer

    def data_received(self, data: bytes) -> None:
        """Pass it on."""
        self._peer.write(data)

    def eof_received(self) -> bool:
        """The other end sent all it will: so does the relay (a half-close carries over where
        the peer's transport can write one; else the peer is closed once flushed)."""
        if self._peer.can_write_eof():
            self._peer.write_eof()
            return True
        self._peer.close()
        return False

    def connection_lost(self, exc: Exception | None) -> None:
        """Close the peer once what it has queued is written."""
        self._peer.close()

    def pause_writing(self) -> None:
        """Our transport's buffer is full: read no more from the peer."""
        self._peer.pause_reading()

    def resume_writing(self) -> None:
        """Our transport drained: read from the peer again."""
        self._peer.resume_reading()


class Router(asyncio.Protocol):
    """The protocol of a worker's listening socket until the first request's head is in."""

    def __init__(self, auth: Authenticator, serve_ws: Callable[[], asyncio.Protocol],
                 owner_path: str, head_timeout_s: float) -> None:
        self._auth = auth
        self._serve_ws = serve_ws
        self._owner_path = owner_path
        self._head_timeout_s = head_timeout_s
        self._head = bytearray()
        self._decided = False
        self._relay: asyncio.Task[None] | None = None

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        """Start the clock for the head."""
        assert isinstance(transport, asyncio.Transport)
        self._transport = transport
        self._timer = asyncio.get_running_loop().call_later(self._head_timeout_s,
                                                            transport.abort)

    def data_received(self, data: bytes) -> None:
        """Gather the head; once it is in (or too long), decide."""
        self._head += data
        if self._decided:  # read while the relay connects: sent after the head
            return
        end = self._head.find(b"\r\n\r\n")
        if end < 0 and len(self._head) <= MAX_HEAD_BYTES:
            return
        self._decided = True
        self._timer.cancel()
        t = self._transport
        cert = t.get_extra_info("peercert")
        if end >= 0 and robot_upgrade(bytes(self._head[:end]), self._auth, cert):
            protocol = self._serve_ws()
            t.set_protocol(protocol)
            protocol.connection_made(t)
            protocol.data_received(bytes(self._head))
        else:
            t.pause_reading()
            self._relay = asyncio.get_running_loop().create_task(self._relay_to_owner())

    async def _relay_to_owner(self) -> None:
        t = self._transport
        try:
            up, _ = await asyncio.get_running_loop().create_unix_connection(
                lambda: Pump(t), self._owner_path)
        except OSError:
            t.abort()
            return
        if t.is_closing():
            up.close()
            return
        up.write(bytes(self._head))
        t.set_protocol(Pump(up))
        t.resume_reading()

    def eof_received(self) -> bool:
        """The client gave up before its head was in."""
        return False

    def connection_lost(self, exc: Exception | None) -> None:
        """Stop the clock."""
        self._timer.cancel()
