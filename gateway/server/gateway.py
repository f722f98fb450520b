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
import os
import tempfile
from collections.abc import Callable
from types import TracebackType

from gateway.execution.oneshot import monitor
from gateway.runtime.exits import EXIT_JOURNAL, EXIT_SOFTWARE, fatal
from gateway.runtime.journal import JournalError, JournalLock
from gateway.server import gc_tuning
from gateway.server.clock import Clock, RealClock, VirtualClock
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
from gateway.server.wire.auth import Authenticator, AuthError
from gateway.server.wire.connections import (
    ALLOWED,
    FD_RESERVE,
    ConnectionServer,
    raise_fd_limit,
)
from gateway.server.wire.http import PlainRoutes
from gateway.server.wire.session import LinkSession
from gateway.server.wire.tls import server_context
from gateway.server.wire.transport import MemoryClient, memory_pair
from gateway.server.wire.ws_endpoint import WsEndpoint
from gateway.server.workers.pool import WorkerPool
from protocol import AnyMessage, ErrorCode, OperatorCommand

log = logging.getLogger("fleetgate.gateway")


class Gateway(ConnectionServer):
    """The fleetgate gateway server; see the module docstring for how to run it."""

    def __init__(self, config: GatewayConfig | None = None, *, clock: Clock | None = None,
                 fresh: bool = False) -> None:
        config = config if config is not None else GatewayConfig()
        tls = config.tls
        super().__init__(config, Authenticator(
            config.tokens, login_ttl_s=config.login_ttl_s,
            robots_need_cert=tls is not None and tls.client_ca is not None), Metrics())
        self.clock: Clock = clock if clock is not None else RealClock(self.config.speed)
        if config.workers and isinstance(self.clock, VirtualClock):
            raise ValueError("worker processes run in real time: a gateway in virtual time "
                             "serves its robots in its own process (workers = 0)")
        self.engine = Engine(self.config, self.clock, self.metrics)
        self._collectors_paused = False
        if config.lifelong is None:  # a shift keeps rare passes (gc_tuning)
            self.engine.before_start.append(self._pause_collectors)
            self.engine.status_listeners.append(self._collectors_follow)
        self._owner: asyncio.Task[None] | None = None
        self._server: HttpServer | None = None
        self._ws: WsEndpoint | None = None
        self.workers: WorkerPool | None = None
        """The worker processes serving the robots (``config.workers``), once listening."""
        self._private: tempfile.TemporaryDirectory[str] | None = None
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
        else:  # one-shot: the monitor's kernel loaded, the startup heap frozen, before any run
            monitor.warm_up()
            gc_tuning.freeze_startup()
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
        if self.workers is not None:
            await self.workers.stop()
            self.workers = None
        if self._server is not None:
            await self._server.stop()
            self._server = None
        if self._ws is not None:
            await self._ws.close()
            self._ws = None
        await self.close_links()
        if self._owner is not None:
            self._owner.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await self._owner
            self._owner = None
        await self.engine.aclose()
        self._close_journal()
        if self._private is not None:
            self._private.cleanup()
            self._private = None

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
        self.track(asyncio.get_running_loop().create_task(self.serve_link(link)))
        await asyncio.sleep(0)
        return client

    def _pause_collectors(self) -> None:
        """No cyclic collection in this process or its workers while a one-shot run goes on
        (:mod:`~gateway.server.gc_tuning`)."""
        if self._collectors_paused:
            return
        self._collectors_paused = True
        gc_tuning.pause_for_run()
        if self.workers is not None:
            self.workers.pause_collectors(True)

    def _collectors_follow(self, status: str) -> None:
        """The collectors back once the run is complete, and while an operator pauses it (a
        pause may last hours: no garbage waits for the run's end meanwhile); paused again
        when it resumes."""
        if status == "running":
            self._pause_collectors()
        elif status in ("paused", "done") and self._collectors_paused:
            self._collectors_paused = False
            gc_tuning.restore_defaults()
            if self.workers is not None:
                self.workers.pause_collectors(False)

    async def listen(self, host: str | None = None, port: int | None = None) -> int:
        """Serve HTTP (the ASGI app on uvicorn) and websockets on ``host:port`` (config by
        default), over TLS if configured; returns the port. TlsError (a ValueError) if the TLS
        files are bad, OSError if the port cannot be bound."""
        cfg = self.config
        ssl = server_context(cfg.tls) if cfg.tls is not None else None
        fds = raise_fd_limit()
        self._ws = self.ws_endpoint(fds)
        self._server = HttpServer(
            Guard(self.app), self._ws, ssl_context=ssl, head_timeout_s=cfg.handshake_timeout_s,
            keep_alive_s=cfg.keep_alive_s,
            max_connections=max(1, min(cfg.max_http_connections, fds - FD_RESERVE)))
        host, port = host or cfg.host, cfg.port if port is None else port
        if cfg.workers:  # robots on the workers; the rest relayed to this process
            self._private = tempfile.TemporaryDirectory(prefix="fleetgate-")
            owner_path = os.path.join(self._private.name, "owner.sock")
            await self._server.start_unix(owner_path)
            self.workers = WorkerPool(cfg, self.engine.queue, self.clock, self.metrics)
            self.engine.holding.append(self.workers.hold)
            self.engine.after_commit.append(self.workers.flush)
            try:
                self.port = await self.workers.start(host, port, owner_path)
            except RuntimeError as exc:
                raise ValueError(str(exc)) from None
        else:
            self.port = await self._server.start(host, port)
        log.info("listening", extra={"host": host, "port": self.port, "tls": ssl is not None,
                                     "max_connections": self.max_connections,
                                     "workers": cfg.workers})
        return self.port

    # ------------------------------------------------------------------------ connections
    def _alive(self) -> bool:
        return self._owner is not None and not self._owner.done()

    def _health(self) -> tuple[bool, bytes]:
        alive = self._alive()
        return alive, json.dumps({"status": "ok" if alive else "down",
                                  "gateway": self.engine.status,
                                  "robots": self.engine.connected_robots()}).encode()

    def _ready(self) -> bool:
        return self._alive() and self._server is not None and self._server.is_serving()

    def _opened(self, session: LinkSession) -> None:
        self.engine.queue.put_nowait(Connected(session))

    def _received(self, session: LinkSession, message: AnyMessage, received: float) -> None:
        self.engine.queue.put_nowait(Inbound(session, message, received, self.clock.now_ms()))

    def _closed(self, session: LinkSession) -> None:
        self.engine.queue.put_nowait(Disconnected(session))


__all__ = ["ALLOWED", "AuthError", "CommandError", "Gateway", "MemoryClient"]
