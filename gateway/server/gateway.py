"""The gateway: one engine (the executor's owner task) behind any number of transports.

Usage (real time, websockets)::

    gw = Gateway(load_config())
    async with gw:
        port = await gw.listen()            # ws://host:port/ws, plus /metrics /healthz /
        await gw.wait_done()

Usage (driver 2: virtual time, in-memory transport)::

    async def main():
        async with Gateway(config, clock=VirtualClock()) as gw:
            client = await gw.connect("demo-robot-0")  # a MemoryClient, like a ws client
            ...
    run_virtual(main())

Connection handlers (:meth:`Gateway.serve_link`) only rate-limit, decode, check the sender's
role and identity, and enqueue; everything else happens in the engine's owner task. No
exception escapes a handler: an unexpected one is logged as one line and the connection is
closed with 1011 (:class:`protocol.CloseCode`).

Transport defences of the websocket server: TLS and mutual TLS (``config.tls``), credentials and
``Origin`` checked at the upgrade (:mod:`gateway.server.wire.auth`; bad requests get 400/401/403,
never 500), handshake, hello and idle timeouts, frames of at most ``HARD_MAX_BYTES`` (1009),
text frames only, at most ``max_connections`` connections (503) and the soft limit of open
files raised to the hard one.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
import resource
import time
import weakref
from collections.abc import Callable
from types import TracebackType

from websockets.asyncio.server import ServerConnection
from websockets.http11 import Request, Response

from gateway.runtime.exits import EXIT_JOURNAL, EXIT_SOFTWARE, fatal
from gateway.runtime.journal import JournalError, JournalLock
from gateway.server import gc_tuning
from gateway.server.clock import Clock, RealClock
from gateway.server.config import GatewayConfig
from gateway.server.engine import Engine
from gateway.server.http_app import Guard, create_app
from gateway.server.items import Connected, Disconnected, Inbound, InternalCommand
from gateway.server.journal_open import open_journal
from gateway.server.metrics import Metrics
from gateway.server.operator_commands import CommandError
from gateway.server.planner import InstanceError, resolve_instance
from gateway.server.runs.lifelong import LifelongRun, shift_from
from gateway.server.task_api.api import TaskApi
from gateway.server.wire.asgi_server import HttpServer
from gateway.server.wire.auth import Authenticator, AuthError, Peer, origin_allowed, single_header
from gateway.server.wire.deadline import IdleDeadline
from gateway.server.wire.http import PlainRoutes
from gateway.server.wire.session import Outbox, Session
from gateway.server.wire.tls import server_context
from gateway.server.wire.transport import (
    HARD_MAX_BYTES,
    Link,
    LinkClosed,
    MemoryClient,
    WebSocketLink,
    memory_pair,
)
from gateway.server.wire.ws_endpoint import WsEndpoint
from protocol import (
    OPERATOR_TYPES,
    ROBOT_TYPES,
    WORLD_TYPES,
    AnyMessage,
    CloseCode,
    ErrorCode,
    Hello,
    OperatorCommand,
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


def _restore_gc_when_done(status: str) -> None:
    if status == "done":
        gc_tuning.restore_defaults()


class Gateway:
    """The fleetgate gateway server; see the module docstring for how to run it."""

    def __init__(self, config: GatewayConfig | None = None, *, clock: Clock | None = None,
                 fresh: bool = False) -> None:
        self.config = config if config is not None else GatewayConfig()
        self.clock: Clock = clock if clock is not None else RealClock(self.config.speed)
        self.metrics = Metrics()
        tls = self.config.tls
        self.auth = Authenticator(
            self.config.tokens, login_ttl_s=self.config.login_ttl_s,
            robots_need_cert=tls is not None and tls.client_ca is not None)
        self.engine = Engine(self.config, self.clock, self.metrics)
        self.engine.before_start.append(gc_tuning.tune_for_run)
        self.engine.status_listeners.append(_restore_gc_when_done)
        self._owner: asyncio.Task[None] | None = None
        self._server: HttpServer | None = None
        self._ws: WsEndpoint | None = None
        self._ws_peers: weakref.WeakKeyDictionary[ServerConnection, Peer] = (
            weakref.WeakKeyDictionary())
        self._links: set[asyncio.Task[None]] = set()
        self._sessions: set[Session] = set()
        self._outbox: Outbox | None = None  # (made in the event loop, by the first connection)
        self._max_connections = self.config.max_connections
        self.http = PlainRoutes(self.metrics.render, self._health, self._ready, self.auth,
                                tls=tls is not None, static_dir=self.config.static_dir)
        self.task_api = TaskApi(self.engine, self.auth, tls=tls is not None,
                                allowed_origins=self.config.allowed_origins,
                                body_timeout_s=self.config.handshake_timeout_s)
        self.app = create_app()
        """The ASGI application (:mod:`gateway.server.http_app`)."""
        self.app.state.task_api = self.task_api
        self.app.state.plain = self.http
        self.port: int | None = None
        """The bound port once :meth:`listen` returned."""
        self._fresh = fresh
        self._lock: JournalLock | None = None
        self.fatal: Callable[[str, int], None] = fatal
        """How the gateway ends the process when it cannot go on (a journal write failed, the
        owner task died): :func:`gateway.runtime.exits.fatal`."""
        self.resumed = False
        """Whether :meth:`start` resumed a journaled run."""

    # ------------------------------------------------------------------------ lifecycle
    async def start(self) -> None:
        """Start the owner task and load the configured instance, if any."""
        if self._owner is not None:
            return
        self.clock.reset()
        cfg = self.config
        if cfg.lifelong is not None:  # a shift: its tasks are journaled (task_journal.py)
            self.engine.current_run = LifelongRun(self.engine, shift_from(cfg))
        try:
            self.resumed = self._resume()
        except BaseException:
            self._abort_start()
            raise
        if (run := self.engine.lifelong) is not None:
            await run.planner_ready()  # its process started while the journal replayed
            # the shift is the run from now on (its pool takes tasks before it starts): a WMS
            # filling it is served with the run's collector settings, not with full passes
            # over the gateway's startup heap every ~70,000 allocations
            gc_tuning.tune_for_run()
            self._start_owner()
            self.engine.operator.maybe_autostart()
            return
        configured = cfg.instance is not None or (
            cfg.map is not None and (cfg.scen or cfg.agents))
        if configured and not self.resumed:  # a resumed run goes on instead
            try:
                problem = resolve_instance(cfg.map or "", cfg.scen, cfg.agents,
                                           cfg.generate_seed, cfg.instance)
            except InstanceError as exc:
                raise ValueError(f"cannot load the configured instance: {exc}") from None
            self.engine.load(problem)
        self._start_owner()

    def _start_owner(self) -> None:
        """Start the owner task; if it ever ends but by :meth:`stop`, the process ends too (one
        line, a non-zero exit for the supervisor): never a gateway that listens and does
        nothing."""
        self._owner = asyncio.get_running_loop().create_task(self.engine.run(), name="owner")
        self._owner.add_done_callback(self._owner_done)

    def _owner_done(self, task: asyncio.Task[None]) -> None:
        if task.cancelled() or task is not self._owner:
            return
        exc = task.exception()
        if isinstance(exc, (KeyboardInterrupt, SystemExit)):
            return  # Ctrl-C or an exit inside the owner: it leaves the loop on its own way out
        self.fatal(f"the gateway's owner task ended: {type(exc).__name__}: {exc}"
                   if exc is not None else "the gateway's owner task ended", EXIT_SOFTWARE)

    def _journal_failed(self, message: str) -> None:
        """A journal write or sync failed: stop before anything it would acknowledge leaves."""
        self.fatal(f"journal write failed, stopping (nothing more is acknowledged): {message}",
                   EXIT_JOURNAL)

    def _resume(self) -> bool:
        """Open the journal (locked, checked against the configuration) and rebuild the run
        or shift it holds; True if one goes on. ValueError (one line) if it cannot."""
        cfg, engine = self.config, self.engine
        if cfg.journal is None:
            return False
        try:
            engine.journal, self._lock = open_journal(cfg, self._fresh)
            engine.journal.on_failure = self._journal_failed
            return engine.resume()
        except JournalError as exc:
            raise ValueError(str(exc)) from None
        except Exception as exc:  # a replay the journal's checks let through, yet failed
            log.debug("replay failed", exc_info=True)
            raise ValueError(f"cannot resume the journal {cfg.journal}: "
                             f"{type(exc).__name__}: {exc}") from None

    def _abort_start(self) -> None:
        """A start that failed: end the planner process, close the journal, release it."""
        self.engine.current_run.cancel()
        self._close_journal()

    def _close_journal(self) -> None:
        """Close the journal (committing what is buffered) and give its lock up."""
        if self.engine.journal is not None:
            self.engine.journal.close()
            self.engine.journal = None
        if self._lock is not None:
            self._lock.release()
            self._lock = None

    async def stop(self) -> None:
        """Close every connection and stop the owner task."""
        self.task_api.closing = True
        if self._server is not None:
            await self._server.stop()
            self._server = None
        if self._ws is not None:
            await self._ws.close()
            self._ws = None
        for session in list(self._sessions):
            session.close(1001, "gateway shutting down")
        for task in list(self._links):
            task.cancel()
        await asyncio.gather(*self._links, return_exceptions=True)
        if self._owner is not None:
            self._owner.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await self._owner
            self._owner = None
        await self.engine.aclose()
        self._close_journal()

    async def __aenter__(self) -> Gateway:
        await self.start()
        return self

    async def __aexit__(self, exc_type: type[BaseException] | None,
                        exc: BaseException | None, tb: TracebackType | None) -> None:
        await self.stop()

    # ------------------------------------------------------------------------ API
    @property
    def status(self) -> str:
        """The engine's status (empty, planning, loaded, running, paused, replanning, done)."""
        return self.engine.status

    @property
    def sessions(self) -> frozenset[Session]:
        """The sessions of the connections open now (authenticated, websocket or memory)."""
        return frozenset(self._sessions)

    @property
    def pending_handshakes(self) -> int:
        """Websocket handshakes authenticated whose connection is not served (yet)."""
        return len(self._ws_peers)

    @property
    def latencies_ms(self) -> list[float]:
        """Finish-received -> dispatch-queued latency of every dispatch a finish unlocked."""
        return self.engine.latencies_ms

    async def command(self, message: OperatorCommand) -> tuple[ErrorCode | None, str]:
        """Run an operator command through the owner task; ``(None, detail)`` if accepted,
        ``(code, detail)`` if refused. ``load_instance`` answers once planning is done."""
        reply: asyncio.Future[tuple[ErrorCode | None, str]] = (
            asyncio.get_running_loop().create_future())
        self.engine.queue.put_nowait(InternalCommand(message, reply))
        return await reply

    async def wait_done(self) -> tuple[float, float]:
        """Wait until the current execution completes; returns ``(soc_ms, makespan_ms)``."""
        await self.engine.finished_event.wait()
        assert self.engine.summary is not None
        return self.engine.summary

    async def connect(self, token: str) -> MemoryClient:
        """Open an in-memory connection (driver 2); AuthError as a websocket 401/403 would."""
        peer = self.auth.identify(token)
        client, link = memory_pair(peer, self.config.send_queue)
        self._track(asyncio.get_running_loop().create_task(self.serve_link(link)))
        await asyncio.sleep(0)
        return client

    async def listen(self, host: str | None = None, port: int | None = None) -> int:
        """Serve HTTP (the ASGI app on uvicorn) and websockets on ``host:port`` (config by
        default), over TLS if configured; returns the port. TlsError (a ValueError) if the TLS
        files are bad, OSError if the port cannot be bound."""
        cfg = self.config
        ssl = server_context(cfg.tls) if cfg.tls is not None else None
        fds = raise_fd_limit()
        self._max_connections = max(1, min(cfg.max_connections, fds - FD_RESERVE))
        self._ws = WsEndpoint(
            self._ws_handler, self._process_request, max_size=HARD_MAX_BYTES,
            open_timeout=cfg.handshake_timeout_s, ping_interval=cfg.ping_interval_s,
            ping_timeout=cfg.ping_timeout_s, close_timeout=cfg.close_timeout_s, max_queue=64)
        self._server = HttpServer(
            Guard(self.app), self._ws, ssl_context=ssl, head_timeout_s=cfg.handshake_timeout_s,
            keep_alive_s=cfg.keep_alive_s,
            max_connections=max(1, min(cfg.max_http_connections, fds - FD_RESERVE)))
        self.port = await self._server.start(host or cfg.host, cfg.port if port is None else port)
        log.info("listening", extra={"host": host or cfg.host, "port": self.port,
                                     "tls": ssl is not None,
                                     "max_connections": self._max_connections})
        return self.port

    # ------------------------------------------------------------------------ connections
    def _track(self, task: asyncio.Task[None]) -> None:
        self._links.add(task)
        task.add_done_callback(self._links.discard)

    def _alive(self) -> bool:
        return self._owner is not None and not self._owner.done()

    def _health(self) -> tuple[bool, bytes]:
        alive = self._alive()
        return alive, json.dumps({"status": "ok" if alive else "down",
                                  "gateway": self.engine.status,
                                  "robots": self.engine.connected_robots()}).encode()

    def _ready(self) -> bool:
        return self._alive() and self._server is not None and self._server.is_serving()

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
        """Run one authenticated connection until it closes (both transports use this).

        With ``timeouts`` (websockets; never in virtual time) a robot must say hello within
        ``hello_timeout_s`` and then send something at least every ``idle_timeout_s``.
        """
        cfg = self.config
        if self._outbox is None:
            self._outbox = Outbox()
        session = Session(link, queue_size=cfg.send_queue, max_errors=cfg.max_errors,
                          outbox=self._outbox,
                          error_decay_s=cfg.error_decay_s,
                          rate_per_s=cfg.rate_per_s, rate_burst=cfg.rate_burst,
                          on_error=lambda code: self.metrics.errors.labels(code.value).inc())
        self._sessions.add(session)
        queue = self.engine.queue
        queue.put_nowait(Connected(session))
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
                    queue.put_nowait(Inbound(session, message, time.perf_counter(),
                                             self.clock.now_ms()))
        except LinkClosed:
            pass
        except Exception as exc:  # a bug: one line, close 1011, the gateway carries on
            log.error("connection handler failed", extra={"peer": str(session),
                                                          "error": repr(exc)[:500]})
            self.metrics.handler_failures.inc()
            session.close(CloseCode.INTERNAL, "internal error")
        finally:
            if deadline is not None:
                deadline.cancel()
            self._sessions.discard(session)
            queue.put_nowait(Disconnected(session))
            session.close()
            with contextlib.suppress(Exception):
                await asyncio.wait_for(asyncio.shield(session.writer), 1.0)

    def _admit(self, session: Session, raw: str | bytes) -> AnyMessage | None:
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


__all__ = ["ALLOWED", "AuthError", "CommandError", "Gateway", "MemoryClient"]
