"""The websocket side of a process that serves connections: the checks of an upgrade, one
:class:`~gateway.server.wire.session.LinkSession` per connection, the receive loop (hello and
idle deadlines) and the admission of each message (rate limit, decoding, the sender's role and
identity). Shared, unchanged, by the one-process gateway (:class:`~gateway.server.gateway.
Gateway`, which hands what it admits to its engine) and by a worker process
(:class:`~gateway.server.workers.worker.Worker`, which passes it to the owner's process).

A subclass says where admitted traffic goes: :meth:`ConnectionServer._opened`,
:meth:`ConnectionServer._received` and :meth:`ConnectionServer._closed`.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import resource
import time
import weakref
from abc import ABC, abstractmethod

from websockets.asyncio.server import ServerConnection
from websockets.http11 import Request, Response

from gateway.server.config import GatewayConfig
from gateway.server.metrics import Metrics
from gateway.server.per_turn import PerTurn
from gateway.server.wire.auth import Authenticator, AuthError, Peer, origin_allowed, single_header
from gateway.server.wire.deadline import IdleDeadline
from gateway.server.wire.session import LinkSession, wake_writers
from gateway.server.wire.transport import HARD_MAX_BYTES, Link, LinkClosed, WebSocketLink
from gateway.server.wire.ws_endpoint import WsEndpoint
from protocol import (
    OPERATOR_TYPES,
    ROBOT_TYPES,
    WORLD_TYPES,
    AnyMessage,
    CloseCode,
    ErrorCode,
    Hello,
    ProtocolError,
    State,
    decode,
    parse_action_id,
)
from protocol.codec import BINARY_FRAME

log = logging.getLogger("fleetgate.gateway")

ALLOWED: dict[str, frozenset[str]] = {
    "robot": ROBOT_TYPES, "operator": OPERATOR_TYPES, "world": WORLD_TYPES,
}
"""Which message types each role may send."""

FD_RESERVE = 64
"""File descriptors kept free for logs, the trace and static files when capping connections."""


def raise_fd_limit() -> int:
    """Raise the soft limit of open files to the hard one; returns the soft limit now."""
    soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    if soft != hard:
        with contextlib.suppress(ValueError, OSError):
            resource.setrlimit(resource.RLIMIT_NOFILE, (hard, hard))
            soft = hard
    return soft if soft != resource.RLIM_INFINITY else 1 << 20


def _refuse(connection: ServerConnection, status: int, text: str,
            header: tuple[str, str] | None = None) -> Response:
    """A websocket upgrade's refusal: ``status``, one line of text, and ``header``."""
    answer = connection.respond(status, f"{text}\n")
    if header is not None:
        answer.headers[header[0]] = header[1]
    return answer


class ConnectionServer(ABC):
    """Serves authenticated connections; admitted traffic goes to the subclass's hooks."""

    def __init__(self, config: GatewayConfig, auth: Authenticator, metrics: Metrics) -> None:
        self.config = config
        self.auth = auth
        self.metrics = metrics
        self._ws_peers: weakref.WeakKeyDictionary[ServerConnection, Peer] = (
            weakref.WeakKeyDictionary())
        self._links: set[asyncio.Task[None]] = set()
        self._sessions: set[LinkSession] = set()
        # made in the event loop, by the first session:
        self._wakeups: PerTurn[LinkSession] | None = None
        self._max_connections = config.max_connections

    # ------------------------------------------------------------------ where traffic goes
    @abstractmethod
    def _opened(self, session: LinkSession) -> None:
        """A connection was authenticated and its session made."""

    @abstractmethod
    def _received(self, session: LinkSession, message: AnyMessage, received: float) -> None:
        """An admitted message (``received``: ``time.perf_counter()`` at its arrival)."""

    @abstractmethod
    def _closed(self, session: LinkSession) -> None:
        """The connection ended."""

    # ------------------------------------------------------------------ websockets
    @property
    def sessions(self) -> frozenset[LinkSession]:
        """The sessions of the connections open now (authenticated) in this process."""
        return frozenset(self._sessions)

    @property
    def max_connections(self) -> int:
        """The cap of open websocket connections of this process."""
        return self._max_connections

    @property
    def pending_handshakes(self) -> int:
        """Websocket handshakes authenticated whose connection is not served (yet)."""
        return len(self._ws_peers)

    def ws_endpoint(self, fds: int) -> WsEndpoint:
        """The websocket endpoint for this process (connections capped by ``fds``, the limit
        of open files)."""
        cfg = self.config
        self._max_connections = max(1, min(cfg.max_connections, fds - FD_RESERVE))
        return WsEndpoint(
            self._ws_handler, self._process_request, max_size=HARD_MAX_BYTES,
            open_timeout=cfg.handshake_timeout_s, ping_interval=cfg.ping_interval_s,
            ping_timeout=cfg.ping_timeout_s, close_timeout=cfg.close_timeout_s, max_queue=64)

    def track(self, task: asyncio.Task[None]) -> None:
        """Keep ``task`` (a connection's) until it ends; :meth:`close_links` cancels it."""
        self._links.add(task)
        task.add_done_callback(self._links.discard)

    def _process_request(self, connection: ServerConnection, request: Request
                         ) -> Response | None:
        """The checks of a websocket upgrade (None accepts it). Never raises: a malformed
        request gets 400, refused credentials 401/403, too many connections 503, anything
        unexpected 500 with one log line."""
        try:
            if len(self._sessions) >= self._max_connections:
                return _refuse(connection, 503, "too many connections", ("Retry-After", "5"))
            tls = self.config.tls is not None
            if not origin_allowed(request.headers, tls, self.config.allowed_origins):
                raise AuthError(403, "foreign Origin")
            single_header(request.headers, "Upgrade")
            cert = connection.transport.get_extra_info("peercert") if tls else None
            self._ws_peers[connection] = self.auth.handshake(request.headers, request.path,
                                                             cert)
        except AuthError as exc:
            log.warning("handshake refused", extra={"status": exc.status, "why": exc.reason})
            self.metrics.refused.labels(str(exc.status)).inc()
            extra = ("WWW-Authenticate", "Bearer") if exc.status == 401 else None
            return _refuse(connection, exc.status, exc.reason, extra)
        except Exception as exc:
            log.error("request failed", extra={"path": request.path[:200], "error": repr(exc)})
            return _refuse(connection, 500, "internal error")
        return None

    async def _ws_handler(self, connection: ServerConnection) -> None:
        peer = self._ws_peers.pop(connection, None)
        if peer is None:  # cannot happen: process_request accepted it
            await connection.close(CloseCode.INTERNAL, "not authenticated")
            return
        task = asyncio.current_task()
        assert task is not None
        self._links.add(task)
        try:
            await self.serve_link(WebSocketLink(connection, peer), timeouts=True)
        finally:
            self._links.discard(task)

    async def serve_link(self, link: Link, *, timeouts: bool = False) -> None:
        """Run one authenticated connection until it closes (every transport uses this).

        With ``timeouts`` (websockets; never in virtual time) a robot must say hello within
        ``hello_timeout_s`` and then send something at least every ``idle_timeout_s``.
        """
        cfg = self.config
        if self._wakeups is None:
            self._wakeups = PerTurn(wake_writers)
        session = LinkSession(link, queue_size=cfg.send_queue, max_errors=cfg.max_errors,
                              wakeups=self._wakeups,
                              error_decay_s=cfg.error_decay_s,
                              rate_per_s=cfg.rate_per_s, rate_burst=cfg.rate_burst,
                              on_error=lambda code: self.metrics.errors.labels(code.value).inc())
        self._sessions.add(session)
        self._opened(session)
        deadline = None
        if timeouts and session.peer.role == "robot":
            task = asyncio.current_task()
            assert task is not None
            deadline = IdleDeadline(task, cfg.hello_timeout_s)
        greeted = False
        try:
            while not session.closing:
                try:
                    raw = await link.recv()
                except asyncio.CancelledError:
                    if deadline is None or not deadline.consume_expiry():
                        raise
                    code = CloseCode.IDLE_TIMEOUT if greeted else CloseCode.HELLO_TIMEOUT
                    session.close(code, f"{'idle' if greeted else 'no hello'} for "
                                        f"{deadline.limit} s")
                    break
                if deadline is not None:
                    deadline.touch()
                message = self._admit(session, raw)
                if message is not None:
                    if not greeted and isinstance(message, Hello):
                        greeted = True
                        if deadline is not None:
                            deadline.set_limit(cfg.idle_timeout_s)
                    self._received(session, message, time.perf_counter())
        except LinkClosed:
            pass
        except Exception as exc:  # a bug: one line, close 1011, the process carries on
            log.error("connection handler failed", extra={"peer": str(session),
                                                          "error": repr(exc)[:500]})
            self.metrics.handler_failures.inc()
            session.close(CloseCode.INTERNAL, "internal error")
        finally:
            if deadline is not None:
                deadline.cancel()
            self._sessions.discard(session)
            self._closed(session)
            session.close()
            with contextlib.suppress(Exception):
                await asyncio.wait_for(asyncio.shield(session.writer), 1.0)

    def _admit(self, session: LinkSession, raw: str | bytes) -> AnyMessage | None:
        """Validate one message from a peer; reply ``error`` and return None if it is bad."""
        if not session.allow():
            session.error(ErrorCode.RATE_LIMITED, None, "too many messages")
            return None
        if isinstance(raw, bytes):
            session.error(ErrorCode.MALFORMED, None, BINARY_FRAME)
            return None
        try:
            message = decode(raw)
        except ProtocolError as exc:
            session.error(exc.code, exc.ref, exc.detail)
            return None
        peer = session.peer
        if message.type not in ALLOWED[peer.role]:
            session.error(ErrorCode.FORBIDDEN, message.msg_id,
                          f"a {peer.role} may not send {message.type}")
            return None
        if peer.role == "robot":
            if isinstance(message, Hello | State):
                about = message.robot_id
            else:
                about = parse_action_id(message.action_id)[1]  # type: ignore[union-attr]
            if about != peer.robot_id:
                session.error(ErrorCode.NOT_YOURSELF, message.msg_id,
                              f"robot {peer.robot_id} may not report about robot {about}")
                return None
        return message

    async def close_links(self) -> None:
        """Close every connection (1001) and wait for their handlers."""
        for session in list(self._sessions):
            session.close(1001, "gateway shutting down")
        for task in list(self._links):
            task.cancel()
        await asyncio.gather(*self._links, return_exceptions=True)
