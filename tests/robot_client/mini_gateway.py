"""A minimal gateway for client tests, speaking protocol v1: over real websockets on
127.0.0.1 (:meth:`MiniGateway.start`), or in memory as the client's connector
(:meth:`MiniGateway.connect`, for tests in virtual time).

It checks the bearer token at the handshake (401 otherwise), can refuse every connection
(503) to hold a link down, and hands each accepted connection to the test, which scripts the
gateway's side message by message.
"""

from __future__ import annotations

import asyncio
import uuid
from typing import Any, Protocol, TypeVar

from websockets.asyncio.server import Server, ServerConnection, serve
from websockets.datastructures import Headers
from websockets.exceptions import InvalidStatus
from websockets.http11 import Request, Response

from gateway.server.wire.auth import Peer
from gateway.server.wire.transport import MemoryClient, memory_pair
from protocol import AnyMessage, decode, encode
from robot_client.config import RobotSettings

M = TypeVar("M")


class Link(Protocol):
    """The gateway's end of a connection: a websockets server connection or a memory link."""

    async def send(self, text: str) -> None:
        """Send one text frame."""
        ...

    async def recv(self) -> str | bytes:
        """The next frame."""
        ...

    async def close(self, code: int = 1000, reason: str = "") -> None:
        """Close the connection."""
        ...


class Conn:
    """The gateway's end of one robot connection."""

    def __init__(self, ws: Link) -> None:
        self.ws = ws
        self.seq = 0
        self.received: list[AnyMessage] = []
        self._unclaimed: list[AnyMessage] = []

    async def send(self, cls: type[AnyMessage], **fields: Any) -> None:
        """Send a message of type ``cls`` with a fresh msg_id and the next seq."""
        msg = cls(msg_id=uuid.uuid4().hex, seq=self.seq, **fields)
        self.seq += 1
        await self.ws.send(encode(msg))

    async def expect(self, cls: type[M], action_id: str | None = None,
                     timeout_s: float = 15.0) -> M:
        """The first received message of type ``cls`` (and ``action_id``) that no earlier
        ``expect`` returned, waiting for it if needed: messages may arrive in any order."""

        def matches(msg: AnyMessage) -> bool:
            return isinstance(msg, cls) and (
                action_id is None or getattr(msg, "action_id", None) == action_id)

        async with asyncio.timeout(timeout_s):
            while True:
                for msg in self._unclaimed:
                    if matches(msg):
                        self._unclaimed.remove(msg)
                        return msg  # type: ignore[return-value]
                msg = decode(await self.ws.recv())
                self.received.append(msg)
                self._unclaimed.append(msg)

    def of_type(self, cls: type[M]) -> list[M]:
        """Every received message of type ``cls`` so far."""
        return [m for m in self.received if isinstance(m, cls)]


class MiniGateway:
    """Accepts robot connections with the right token; see module doc."""

    def __init__(self, token: str) -> None:
        self.token = token
        self.refuse = False
        self.attempts = 0
        self.connections: asyncio.Queue[Conn] = asyncio.Queue()
        self._server: Server | None = None

    async def start(self) -> int:
        """Listen on an ephemeral loopback port; return it."""
        self._server = await serve(self._handler, "127.0.0.1", 0,
                                   process_request=self._check)
        return int(self._server.sockets[0].getsockname()[1])

    def _refusal(self, authorization: str | None) -> tuple[int, str] | None:
        """Count an attempt; the HTTP status and body it is refused with, if it is."""
        self.attempts += 1
        if self.refuse:
            return 503, "down\n"
        if authorization != f"Bearer {self.token}":
            return 401, "bad token\n"
        return None

    def _check(self, connection: ServerConnection, request: Request) -> Response | None:
        refusal = self._refusal(request.headers.get("Authorization"))
        return None if refusal is None else connection.respond(*refusal)

    async def connect(self, settings: RobotSettings) -> MemoryClient:
        """The robot client's connector in memory: refused as the handshake would be
        (InvalidStatus 503 or 401), else a connection handed to :meth:`accept`."""
        refusal = self._refusal(f"Bearer {settings.token.get_secret_value()}")
        if refusal is not None:
            raise InvalidStatus(Response(refusal[0], "refused", Headers(), refusal[1].encode()))
        client, link = memory_pair(Peer("robot", settings.robot_id))
        await self.connections.put(Conn(link))
        return client

    async def _handler(self, ws: ServerConnection) -> None:
        await self.connections.put(Conn(ws))
        await ws.wait_closed()

    async def accept(self, timeout_s: float = 10.0) -> Conn:
        """The next robot connection."""
        return await asyncio.wait_for(self.connections.get(), timeout_s)

    async def close(self) -> None:
        """Stop listening and close every connection."""
        if self._server is not None:
            self._server.close()
            await self._server.wait_closed()
