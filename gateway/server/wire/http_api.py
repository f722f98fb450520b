"""HTTP requests with bodies and streams on the gateway's port (the websocket server only
answers bodiless GETs): the task API's routes are taken off the websocket server here.

:func:`routing_connection` makes the websocket server's connection class read each new
connection's request head first. A request for a path of :data:`API_PREFIXES` is an
:class:`ApiRequest` for the API's handler: head, then a body of at most ``MAX_BODY_BYTES``
(``Content-Length``, or ``Transfer-Encoding: chunked``), within the handshake timeout;
anything else goes on to the websocket server unchanged (the upgrade, the GUI's files,
probes) if it is a bodiless GET, else it is refused here (405, or 400 for a body): the
websocket server would drop it unanswered. One request per connection
(``Connection: close``); a handler answers with a complete :class:`ApiResponse` or a stream
of chunks (server-sent events) that ends when the client goes or the gateway stops.
``Expect: 100-continue`` is answered before the body is read. Over TLS the same applies: the
head is read after the TLS handshake.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
from collections.abc import AsyncIterator, Awaitable, Callable
from dataclasses import dataclass, field
from typing import Any
from urllib.parse import urlsplit

from websockets.asyncio.server import ServerConnection
from websockets.datastructures import Headers

from gateway.server.task_api.models import MAX_BODY_BYTES
from gateway.server.wire.http import REASONS, SECURITY_HEADERS

log = logging.getLogger("fleetgate.http")

API_PREFIXES = ("/tasks",)
"""Paths (and their sub-paths) served by the API handler."""
MAX_HEAD_BYTES = 16 * 1024
"""A request head longer than this goes to the websocket server, which refuses it."""
MAX_HEADERS = 64
CHUNKED = -2
"""The body's length when it comes in chunks (``Transfer-Encoding: chunked``)."""
HEX_DIGITS = b"0123456789abcdefABCDEF"


class HttpError(Exception):
    """A request is refused with ``status`` and a one-line message (JSON ``{"error": ...}``)."""

    def __init__(self, status: int, message: str,
                 headers: list[tuple[str, str]] | None = None) -> None:
        super().__init__(message)
        self.status = status
        self.message = message
        self.headers = headers or []


@dataclass
class ApiRequest:
    """One parsed request: method, path (no query), query string, headers and body."""

    method: str
    path: str
    query: str
    headers: Headers
    body: bytes
    tls: bool = False


@dataclass
class ApiResponse:
    """A complete response, or (``stream`` set) a head followed by the stream's chunks."""

    status: int
    body: bytes = b""
    content_type: str = "application/json"
    headers: list[tuple[str, str]] = field(default_factory=list)
    stream: AsyncIterator[bytes] | None = None


def json_answer(status: int, data: object, headers: list[tuple[str, str]] | None = None
                ) -> ApiResponse:
    """A JSON response."""
    return ApiResponse(status, json.dumps(data).encode(), headers=headers or [])


Handler = Callable[[ApiRequest], Awaitable[ApiResponse]]


def _head_of(status: int, content_type: str, length: int | None,
             extra: list[tuple[str, str]]) -> bytes:
    lines = [f"HTTP/1.1 {status} {REASONS.get(status, 'Error')}",
             f"Content-Type: {content_type}", "Cache-Control: no-store", "Connection: close",
             *(f"{k}: {v}" for k, v in SECURITY_HEADERS),
             *(f"{k}: {v}" for k, v in extra)]
    if length is not None:
        lines.append(f"Content-Length: {length}")
    return ("\r\n".join(lines) + "\r\n\r\n").encode("latin-1")


def _parse_head(head: bytes) -> tuple[str, str, str, Headers]:
    """Method, path, query and headers of a request head; HttpError(400) if malformed."""
    try:
        text = head.decode("ascii")
    except UnicodeDecodeError:
        raise HttpError(400, "the request head is not ASCII") from None
    lines = text.split("\r\n")
    parts = lines[0].split(" ")
    if len(parts) != 3 or parts[2] not in ("HTTP/1.1", "HTTP/1.0"):
        raise HttpError(400, "malformed request line")
    method, target = parts[0], parts[1]
    headers = Headers()
    for line in lines[1:]:
        if not line:
            continue
        name, sep, value = line.partition(":")
        if not sep or not name or name != name.strip():
            raise HttpError(400, f"malformed header line {line[:60]!r}")
        headers[name] = value.strip()
    if len(headers) > MAX_HEADERS:
        raise HttpError(400, f"more than {MAX_HEADERS} headers")
    url = urlsplit(target)
    return method, url.path, url.query, headers


class _Dechunker:
    """Decodes a chunked request body (``Transfer-Encoding: chunked``) as it arrives: each
    call takes the complete chunks at the start of the buffer out of it, so every byte is
    parsed once however the client splits its body (parsing the whole buffer again on every
    read cost a body of one-byte chunks minutes of event-loop CPU)."""

    def __init__(self) -> None:
        self._body = bytearray()

    def __call__(self, data: bytearray) -> bytes | None:
        """The body once its last chunk and trailers are in ``data`` (None: more to come);
        HttpError if it is malformed or over MAX_BODY_BYTES."""
        while True:
            eol = data.find(b"\r\n")
            if eol < 0:
                if len(data) > 100:
                    raise HttpError(400, "malformed chunk size line")
                return None
            size_field = bytes(data[:eol]).split(b";", 1)[0].strip()
            if not size_field or len(size_field) > 8 or size_field.strip(HEX_DIGITS):
                raise HttpError(400, "malformed chunk size line")
            size = int(size_field, 16)
            if len(self._body) + size > MAX_BODY_BYTES:
                raise HttpError(413, f"the body has more than {MAX_BODY_BYTES} bytes")
            if size == 0:  # the last chunk, then trailers (ignored) up to an empty line
                end = data.find(b"\r\n\r\n", eol)
                if end < 0 and len(data) - eol > MAX_HEAD_BYTES:
                    raise HttpError(400, "chunked trailers too long")
                return None if end < 0 else bytes(self._body)
            start = eol + 2
            if len(data) < start + size + 2:
                return None
            if data[start + size:start + size + 2] != b"\r\n":
                raise HttpError(400, "a chunk does not end with CRLF")
            self._body += data[start:start + size]
            del data[:start + size + 2]


def _continue_expected(headers: Headers) -> bool:
    """Whether the client waits for ``100 Continue`` before its body (curl does for large
    bodies); HttpError(417) for any other expectation."""
    expect = headers.get_all("Expect")
    if not expect:
        return False
    if [e.lower() for e in expect] != ["100-continue"]:
        raise HttpError(417, f"unsupported Expect: {', '.join(expect)[:60]} (only "
                             "100-continue)")
    return True


def _not_plain(head: bytes) -> HttpError | None:
    """Why a request for a path outside the API is refused here (the websocket server's routes
    are bodiless GETs; it would drop anything else without an answer), or None: it is one."""
    try:
        method, path, _, headers = _parse_head(head)
    except HttpError:
        return None  # the websocket server refuses it
    if method != "GET":
        return HttpError(405, f"{method} {path[:100]}: only GET is served here",
                         [("Allow", "GET")])
    if "Transfer-Encoding" in headers or set(headers.get_all("Content-Length")) - {"0"}:
        return HttpError(400, f"GET {path[:100]} takes no body")
    return None


def _is_api(head: bytes) -> bool:
    """Whether a request head asks for an API path."""
    line = head.split(b"\r\n", 1)[0].split(b" ")
    if len(line) < 2:
        return False
    path = line[1].split(b"?", 1)[0].decode("latin-1")
    return any(path == p or path.startswith(p + "/") for p in API_PREFIXES)


class RoutingConnection(ServerConnection):
    """A websocket server connection that first reads the request head and takes API requests
    off the websocket server (see the module doc). Subclassed per gateway by
    :func:`routing_connection` with the API's handler and limits."""

    api: Handler
    timeout_s: float = 10.0
    tls: bool = False
    live: set[RoutingConnection]

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self._mode = "sniff"
        self._buffer = bytearray()
        self._body_needed = -1
        self._dechunk = _Dechunker()
        self._head: tuple[str, str, str, Headers] | None = None
        self._timer: asyncio.TimerHandle | None = None
        self._task: asyncio.Task[None] | None = None
        self._raw: asyncio.Transport | None = None

    # ------------------------------------------------------------------ asyncio protocol
    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        self._raw = transport  # type: ignore[assignment]
        self._timer = self.loop.call_later(self.timeout_s, self._too_slow)

    def data_received(self, data: bytes) -> None:
        if self._mode == "ws":
            super().data_received(data)
            return
        self._buffer += data
        if self._mode == "sniff":
            end = self._buffer.find(b"\r\n\r\n")
            if end < 0 and len(self._buffer) <= MAX_HEAD_BYTES:
                return
            head = bytes(self._buffer[:max(end, 0)])
            refusal = _not_plain(head) if end >= 0 and not _is_api(head) else None
            if end < 0 or not (_is_api(head) or refusal):
                self._to_websockets()
                return
            self._mode = "api"
            self._buffer = self._buffer[end + 4:]
            self.live.add(self)
            if refusal is not None:
                self._refuse(refusal)
                return
            try:
                self._head = _parse_head(head)
                self._body_needed = self._body_length(self._head[3])
                if _continue_expected(self._head[3]) and self._body() is None:
                    self._write(b"HTTP/1.1 100 Continue\r\n\r\n")
            except HttpError as exc:
                self._refuse(exc)
                return
        if self._mode == "api" and self._head is not None and self._task is None:
            try:
                body = self._body()
            except HttpError as exc:
                self._refuse(exc)
                return
            if body is None:
                return
            self._cancel_timer()
            method, path, query, headers = self._head
            request = ApiRequest(method, path, query, headers, body, self.tls)
            self._task = self.loop.create_task(self._serve(request))

    def eof_received(self) -> bool | None:  # type: ignore[override]
        if self._mode == "ws":
            return super().eof_received()
        # a half-closed client still gets its answer (TLS has no half-close: asyncio would
        # warn on every request that True has no effect)
        return None if self.tls else True

    def connection_lost(self, exc: Exception | None) -> None:
        self._cancel_timer()
        if self._mode == "ws":
            super().connection_lost(exc)
            return
        self.live.discard(self)
        if self._task is not None and not self._task.done():
            self._task.cancel()

    # ------------------------------------------------------------------ internals
    def _to_websockets(self) -> None:
        """Hand the connection to the websocket server as if it had just been made."""
        self._cancel_timer()
        self._mode = "ws"
        data, self._buffer = bytes(self._buffer), bytearray()
        assert self._raw is not None
        super().connection_made(self._raw)
        super().data_received(data)

    def _cancel_timer(self) -> None:
        if self._timer is not None:
            self._timer.cancel()
            self._timer = None

    def _too_slow(self) -> None:
        self._timer = None
        if self._mode == "sniff":
            self._close()
        elif self._task is None:
            self._refuse(HttpError(408, f"no complete request within {self.timeout_s} s"))

    def _body(self) -> bytes | None:
        """The request's body once it is all there (None: more to come); HttpError."""
        if self._body_needed == CHUNKED:
            return self._dechunk(self._buffer)
        return bytes(self._buffer[:self._body_needed]) \
            if len(self._buffer) >= self._body_needed else None

    @staticmethod
    def _body_length(headers: Headers) -> int:
        """The body's length from the head (or :data:`CHUNKED`); HttpError."""
        codings = headers.get_all("Transfer-Encoding")
        if codings:
            if [c.strip().lower() for c in codings] != ["chunked"]:
                raise HttpError(501, f"Transfer-Encoding {', '.join(codings)[:60]}: only "
                                     "chunked is supported")
            if "Content-Length" in headers:
                raise HttpError(400, "Transfer-Encoding and Content-Length both given")
            return CHUNKED
        lengths = headers.get_all("Content-Length")
        if not lengths:
            return 0
        if len(set(lengths)) > 1 or not lengths[0].isdigit() or len(lengths[0]) > 12:
            raise HttpError(400, "invalid Content-Length")
        length = int(lengths[0])
        if length > MAX_BODY_BYTES:
            raise HttpError(413, f"the body has {length} bytes, more than {MAX_BODY_BYTES}")
        return length

    def _refuse(self, exc: HttpError) -> None:
        body = json.dumps({"error": exc.message}).encode()
        self._write(_head_of(exc.status, "application/json", len(body), exc.headers) + body)
        self._close()

    def _write(self, data: bytes) -> None:
        if self._raw is not None and not self._raw.is_closing():
            self._raw.write(data)

    def _close(self) -> None:
        self._mode = "closed" if self._mode == "sniff" else self._mode
        if self._raw is not None and not self._raw.is_closing():
            self._raw.close()

    async def _serve(self, request: ApiRequest) -> None:
        """Answer one request: the handler's response, or its stream until it ends."""
        try:
            try:
                answer = await self.api(request)
            except HttpError as exc:
                self._refuse(exc)
                return
            if answer.stream is None:
                self._write(_head_of(answer.status, answer.content_type, len(answer.body),
                                     answer.headers) + answer.body)
                return
            self._write(_head_of(answer.status, answer.content_type, None, answer.headers))
            async for chunk in answer.stream:
                if self._raw is None or self._raw.is_closing():
                    break
                self._write(chunk)
                if self._raw.get_write_buffer_size() > MAX_BODY_BYTES:
                    break  # a client that does not read: it resumes from its last event id
        except asyncio.CancelledError:
            pass
        except Exception as exc:  # a bug: one line, 500, the gateway carries on
            log.error("API request failed", extra={"path": request.path[:200],
                                                   "error": repr(exc)[:500]})
            self._refuse(HttpError(500, "internal error"))
        finally:
            self._close()

    def close_api(self) -> None:
        """End an API connection (the gateway stops)."""
        if self._task is not None and not self._task.done():
            self._task.cancel()
        self._close()


def routing_connection(api: Handler, *, timeout_s: float, tls: bool,
                       live: set[RoutingConnection]) -> type[RoutingConnection]:
    """The connection class of one gateway's websocket server (``create_connection``)."""
    return type("GatewayConnection", (RoutingConnection,),
                {"api": staticmethod(api), "timeout_s": timeout_s, "tls": tls, "live": live})


async def close_all(live: set[RoutingConnection]) -> None:
    """End every API connection (streams included) and let their tasks finish."""
    tasks = []
    for conn in list(live):
        conn.close_api()
        if conn._task is not None:
            tasks.append(conn._task)
    with contextlib.suppress(Exception):
        await asyncio.gather(*tasks, return_exceptions=True)
