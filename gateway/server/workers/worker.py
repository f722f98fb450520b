"""A worker process: serves the robots' websockets that land on it and passes them to the
owner (``python -m gateway.server.workers.worker FD``; the owner's
:class:`~gateway.server.workers.pool.WorkerPool` starts it with its end of the channel as
``FD``).

The channel's first frame is the start, ``("start", config, host, port, owner_path)``; the
worker listens on ``host:port`` beside the others (``SO_REUSEPORT``) and answers
``[("ready",)]``. Then it sends its events and carries out the owner's commands, both as the
records of :mod:`~gateway.server.workers.records`, one batch per event-loop turn. The worker
ends when the owner's end closes.
"""

from __future__ import annotations

import asyncio
import contextlib
import pickle
import socket
import sys
from typing import Any

from gateway.server import gc_tuning
from gateway.server.config import GatewayConfig
from gateway.server.logs import configure_logging
from gateway.server.metrics import Metrics
from gateway.server.wire.auth import Authenticator
from gateway.server.wire.connections import ConnectionServer, raise_fd_limit
from gateway.server.wire.session import LinkSession
from gateway.server.wire.tls import server_context
from gateway.server.workers.channel import Channel, Outbox, batch_of, first_done, start_of
from gateway.server.workers.records import (
    ACTION,
    CLOSE,
    CLOSED,
    COLLECTOR,
    ERROR,
    OPENED,
    PING,
    PONG,
    SEND,
    VERSION,
    Op,
    event,
)
from gateway.server.workers.router import Router
from protocol import AnyMessage, ErrorCode


class Worker(ConnectionServer):
    """The robot connections of one worker process."""

    def __init__(self, config: GatewayConfig, outbox: Outbox) -> None:
        tls = config.tls
        super().__init__(config, Authenticator(
            config.tokens, login_ttl_s=config.login_ttl_s,
            robots_need_cert=tls is not None and tls.client_ca is not None), Metrics())
        self._outbox = outbox
        self._by_id: dict[int, LinkSession] = {}
        self._server: asyncio.Server | None = None

    def _opened(self, session: LinkSession) -> None:
        self._by_id[session.id] = session
        self._outbox.put((OPENED, session.id, session.peer.role, session.peer.robot_id))

    def _received(self, session: LinkSession, message: AnyMessage, received: float) -> None:
        self._outbox.put(event(session.id, message, received))

    def _closed(self, session: LinkSession) -> None:
        self._by_id.pop(session.id, None)
        self._outbox.put((CLOSED, session.id))

    async def listen(self, host: str, port: int, owner_path: str) -> None:
        """Listen on ``host:port`` beside the other workers."""
        cfg = self.config
        ssl = server_context(cfg.tls) if cfg.tls is not None else None
        endpoint = self.ws_endpoint(raise_fd_limit())
        self._endpoint = endpoint

        def route() -> Router:
            return Router(self.auth, endpoint.protocol, owner_path, cfg.handshake_timeout_s)

        self._server = await asyncio.get_running_loop().create_server(
            route, host, port, reuse_port=True, ssl=ssl, backlog=4096,
            ssl_handshake_timeout=cfg.handshake_timeout_s if ssl else None)

    def apply(self, ops: list[Op]) -> None:
        """Carry out the owner's commands, in order."""
        for op in ops:
            code = op[0]
            if code == PING:
                self._outbox.put((PONG, self.counts()))
                continue
            if code == COLLECTOR:
                (gc_tuning.pause_for_run if op[1] else gc_tuning.end_pause)()
                continue
            session = self._by_id.get(op[1])
            if session is None:
                continue
            if code == ACTION:
                session.send_action_body(op[2])
            elif code == SEND:
                kind, fields = pickle.loads(op[2])
                session.send(kind, **fields)
            elif code == ERROR:
                session.error(ErrorCode(op[2]), op[3], op[4])
            elif code == CLOSE:
                session.close(op[2], op[3])
            elif code == VERSION:
                session.version = op[2]

    def counts(self) -> dict[str, dict[str, float]]:
        """This worker's counts of protocol errors, refused handshakes and failed handlers
        (their totals so far, by label), for the owner's ``/metrics``."""
        return {name: {_label(sample.labels): sample.value
                       for family in metric.collect() for sample in family.samples
                       if sample.name.endswith("_total")}
                for name, metric in (("errors", self.metrics.errors),
                                     ("refused", self.metrics.refused),
                                     ("handler_failures", self.metrics.handler_failures))}

    async def stop(self) -> None:
        """Stop listening and close every connection (1001)."""
        if self._server is not None:
            self._server.close()
            await self._endpoint.close()
        await self.close_links()


async def serve(fd: int) -> None:
    """Run a worker on the channel ``fd`` until the owner's end closes."""
    loop = asyncio.get_running_loop()
    started: asyncio.Future[tuple[Any, ...]] = loop.create_future()
    channel = await Channel.connect(socket.socket(fileno=fd),
                                    lambda payload: started.set_result(start_of(payload)))
    await first_done(started, channel.closed)
    if not started.done():
        return  # the owner died before it started this worker
    _, config, host, port, owner_path = started.result()  # (no more comes before the ready)
    configure_logging(config.log_level, config.log_format, config.log_file)
    outbox = Outbox(channel.transport, interval_s=config.batch_ms / 1000.0)
    worker = Worker(config, outbox)
    channel.received = lambda payload: worker.apply(batch_of(payload))
    await worker.listen(host, port, owner_path)
    gc_tuning.tune_for_run()
    outbox.put(("ready",))
    try:
        await channel.closed  # the owner stopped (or died): so does this worker
    finally:
        await worker.stop()


def _label(labels: dict[str, str]) -> str:
    return next(iter(labels.values()), "")


def main() -> None:
    """Entry point of a worker process."""
    with contextlib.suppress(KeyboardInterrupt):
        asyncio.run(serve(int(sys.argv[1])))


if __name__ == "__main__":
    main()
