"""The gateway's port: uvicorn (httptools) serving the ASGI application, in the gateway's own
process and event loop, with websocket upgrades handed to :class:`~gateway.server.wire.
ws_endpoint.WsEndpoint`.

uvicorn is chosen for its httptools parser (llhttp, strict: a control character or a bare
line feed in a header is a 400 before any of our code sees the request), its flow control
(a body is read only as the application asks for it, at most 64 KiB ahead) and its
``limit_concurrency`` cap (503); it has no limit on a request head's time or size, so
:class:`GatewayHttpProtocol` adds both (as its documented ``http`` protocol class). The
listening socket and the TLS context (with its handshake timeout and logged failures,
:mod:`gateway.server.wire.tls`) are the gateway's; uvicorn's own runner (signals, its main
loop) is not used.
"""

from __future__ import annotations

import asyncio
import contextlib
import ssl
from typing import Any

from uvicorn import Config
from uvicorn.protocols.http.httptools_impl import HttpToolsProtocol
from uvicorn.server import ServerState

from gateway.server.wire.ws_endpoint import WsEndpoint

MAX_HEAD_BYTES = 16 * 1024
READ_BYTES = 32 * 1024
"""What one read of a connection takes at most (asyncio's default is 256 KiB): with reading
paused once a head is in, what a request's connection holds before its credentials are
checked."""
"""A request head (line and headers) longer than this is refused (400)."""


class Refused(Exception):
    """Raised in a parser callback: uvicorn answers 400 and closes the connection."""


class GatewayHttpProtocol(HttpToolsProtocol):
    """uvicorn's httptools protocol plus the limits it lacks: a request head arrives whole
    within ``head_timeout_s`` of the connection (or of its first byte after a keep-alive
    pause), else the connection is closed; it is at most :data:`MAX_HEAD_BYTES`; and at most
    one request waits behind the one being answered (uvicorn queues pipelined requests
    without a bound while it parses what it has read: bytes a client keeps sending into an
    event stream would pile up), else 400 and the connection is closed."""

    head_timeout_s = 10.0

    def connection_made(self, transport: asyncio.Transport) -> None:  # type: ignore[override]
        """Start the clock for the first request's head."""
        super().connection_made(transport)
        if hasattr(transport, "max_size"):  # asyncio's socket transport: what one recv takes
            transport.max_size = READ_BYTES
        self._head_bytes = 0
        self._body_due = False  # a request's head is in, its body is not whole yet
        self._head_timer: asyncio.TimerHandle | None = self.loop.call_later(
            self.head_timeout_s, self._too_slow)

    def data_received(self, data: bytes) -> None:
        """Parse what was read; then, if a request's head is in but not all of its body, read
        no more until the application asks for the body (uvicorn would read on up to its
        64 KiB high-water mark before the credentials are checked). A request read whole
        (most are: head and body in one read) leaves reading on: no pause and resume."""
        super().data_received(data)
        if self._body_due:
            self.flow.pause_reading()

    def connection_lost(self, exc: Exception | None) -> None:
        """Stop the clock."""
        self._stop_clock()
        super().connection_lost(exc)

    def on_message_begin(self) -> None:
        """A new request: its head has ``head_timeout_s``."""
        if self.pipeline:
            raise Refused
        super().on_message_begin()
        self._head_bytes = 0
        if self._head_timer is None:
            self._head_timer = self.loop.call_later(self.head_timeout_s, self._too_slow)

    def on_url(self, url: bytes) -> None:
        """Count the head's bytes."""
        self._count(len(url))
        super().on_url(url)

    def on_header(self, name: bytes, value: bytes) -> None:
        """Count the head's bytes."""
        self._count(len(name) + len(value) + 4)
        super().on_header(name, value)

    def on_headers_complete(self) -> None:
        """The head is in: no more clock (the application bounds the body's time); its body
        is due (see :meth:`data_received`)."""
        self._stop_clock()
        super().on_headers_complete()
        self._body_due = not self.parser.should_upgrade()

    def on_message_complete(self) -> None:
        """The body is whole."""
        super().on_message_complete()
        self._body_due = False

    def _count(self, n: int) -> None:
        self._head_bytes += n
        if self._head_bytes > MAX_HEAD_BYTES:
            raise Refused

    def _stop_clock(self) -> None:
        if self._head_timer is not None:
            self._head_timer.cancel()
            self._head_timer = None

    def _too_slow(self) -> None:
        self._head_timer = None
        self.transport.close()


class HttpServer:
    """uvicorn on one listening socket (see the module doc)."""

    def __init__(self, app: Any, endpoint: WsEndpoint, *, ssl_context: ssl.SSLContext | None,
                 head_timeout_s: float, keep_alive_s: float, max_connections: int) -> None:
        protocol = type("HttpProtocol", (GatewayHttpProtocol,),
                        {"head_timeout_s": head_timeout_s})
        self._config = Config(app, http=protocol, ws=endpoint.protocol,  # type: ignore[arg-type]
                              lifespan="off", log_config=None, access_log=False,
                              proxy_headers=False, server_header=False,
                              timeout_keep_alive=max(1, round(keep_alive_s)),
                              limit_concurrency=max_connections)
        self._config.load()
        self._ssl = ssl_context
        self._handshake_timeout_s = head_timeout_s
        self._state = ServerState()
        self._server: asyncio.Server | None = None

    @property
    def connections(self) -> int:
        """HTTP connections open now (not websockets: those are the endpoint's)."""
        return len(self._state.connections)

    def is_serving(self) -> bool:
        """Whether it accepts connections."""
        return self._server is not None and self._server.is_serving()

    def _protocol(self) -> asyncio.Protocol:
        config = self._config
        return config.http_protocol_class(  # type: ignore[call-arg]
            config=config, server_state=self._state, app_state={})

    async def start(self, host: str, port: int) -> int:
        """Listen on ``host:port``; the bound port. OSError if it cannot."""
        self._server = await asyncio.get_running_loop().create_server(
            self._protocol, host, port, ssl=self._ssl, backlog=self._config.backlog,
            ssl_handshake_timeout=self._handshake_timeout_s if self._ssl else None)
        return int(self._server.sockets[0].getsockname()[1])

    async def start_unix(self, path: str) -> None:
        """Listen on the unix socket ``path`` instead, without TLS: the worker processes
        relay to it what they do not serve themselves, TLS already terminated
        (:mod:`gateway.server.workers.router`). OSError if it cannot."""
        self._server = await asyncio.get_running_loop().create_unix_server(
            self._protocol, path, backlog=self._config.backlog)

    async def stop(self, grace_s: float = 2.0) -> None:
        """Stop listening, end idle connections and requests in flight (streams are cut after
        ``grace_s``)."""
        if self._server is None:
            return
        self._server.close()
        for conn in list(self._state.connections):
            conn.shutdown()
        tasks = list(self._state.tasks)
        if tasks:
            _, late = await asyncio.wait(tasks, timeout=grace_s)
            for task in late:
                task.cancel()
            with contextlib.suppress(Exception):
                await asyncio.gather(*late, return_exceptions=True)
        for conn in list(self._state.connections):
            conn.transport.abort()
        self._server = None
