"""The robots' and operators' websockets (``/ws``) on the HTTP server's port, served by the
websockets library's own connection class, as before the HTTP surface moved to uvicorn.

uvicorn parses every request; an upgrade to ``websocket`` it hands over (its ``ws`` protocol
slot) to :meth:`WsEndpoint.protocol`, a :class:`websockets.asyncio.server.ServerConnection`
that takes the connection's transport and the request. From there on each frame goes through
the websockets library alone, exactly as when it owned the socket: a robot's CPU per message
is unchanged (measured: ``bench/load.py --robots 1000 --against``), and users keep one port.

The handshake runs ``process_request`` (credentials, Origin, the connection cap) within
``open_timeout``, then the gateway's handler until the connection ends.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
from collections.abc import Awaitable, Callable
from typing import Any

from websockets.asyncio.server import ServerConnection
from websockets.http11 import Request, Response
from websockets.protocol import State
from websockets.server import ServerProtocol

log = logging.getLogger("websockets.server")

ProcessRequest = Callable[[ServerConnection, Request], Response | None]
Handler = Callable[[ServerConnection], Awaitable[None]]


class WsEndpoint:
    """Serves the websocket connections uvicorn hands over (the ``Server`` a websockets
    ``ServerConnection`` belongs to: it starts each one's handler task)."""

    def __init__(self, handler: Handler, process_request: ProcessRequest, *, max_size: int,
                 open_timeout: float, ping_interval: float | None, ping_timeout: float | None,
                 close_timeout: float, max_queue: int) -> None:
        self._handler = handler
        self._process_request = process_request
        self._max_size = max_size
        self._open_timeout = open_timeout
        self._options: dict[str, Any] = {"ping_interval": ping_interval,
                                         "ping_timeout": ping_timeout,
                                         "close_timeout": close_timeout,
                                         "max_queue": max_queue}
        self.handler_tasks: set[asyncio.Task[None]] = set()
        """One task per connection (websockets' ``ServerConnection`` adds it)."""
        self.connections: set[ServerConnection] = set()
        """Connections past their handshake."""
        self.logger = log
        self._serving = True

    def is_serving(self) -> bool:
        """False once :meth:`close` began (a handshake then gets 503)."""
        return self._serving

    def protocol(self, **_uvicorn: Any) -> ServerConnection:
        """A connection for one upgrade request (uvicorn's ``ws`` protocol factory: it gives
        its config and state, which websockets does not need)."""
        return ServerConnection(ServerProtocol(max_size=self._max_size, logger=log),
                                self,  # type: ignore[arg-type]
                                **self._options)

    async def handler(self, connection: ServerConnection) -> None:
        """Handshake within ``open_timeout``, then the gateway's handler; the connection is
        closed when this returns."""
        try:
            async with asyncio.timeout(self._open_timeout):
                await connection.handshake(self._process_request, None, None)
            if connection.protocol.state is not State.OPEN:
                connection.transport.abort()
                return
            connection.start_keepalive()
            self.connections.add(connection)
            try:
                async with connection:
                    await self._handler(connection)
            finally:
                self.connections.discard(connection)
        except Exception:  # a timed-out or broken handshake: nothing is left behind
            connection.transport.abort()
        finally:
            self.handler_tasks.discard(asyncio.current_task())

    async def close(self) -> None:
        """Refuse new handshakes, close open connections (1001) and wait for their tasks."""
        self._serving = False
        closing = [asyncio.create_task(c.close(1001, "gateway shutting down"))
                   for c in self.connections if c.protocol.state is State.OPEN]
        with contextlib.suppress(Exception):
            await asyncio.gather(*closing, *self.handler_tasks, return_exceptions=True)
