"""A worker process: serves the robots' websockets that land on it and passes them to the
owner (``python -m gateway.server.workers.worker FD``; the owner's
:class:`~gateway.server.workers.pool.WorkerPool` starts it with its end of the channel as
``FD``).

The channel's first batch is ``[("start", config, host, port, owner_path)]``; the worker
listens on ``host:port`` beside the others (``SO_REUSEPORT``) and answers ``[("ready",)]``.

Events to the owner, one batch per event-loop turn:

- ``("o", sid, peer)``: a robot's connection was authenticated (``sid``: its session here);
- ``("i", sid, message, received)``: a message it admitted (``received``: perf_counter);
- ``("x", sid)``: the connection ended.

Commands from the owner, applied in order to the session ``sid`` (ignored once it ended):
``("a", sid, fields)`` an action, ``("m", sid, kind, fields)`` any other message, ``("e",
sid, code, ref, detail)`` an error reply, ``("c", sid, code, reason)`` close, ``("v", sid,
version)`` the protocol version to answer in. The worker ends when the owner's end closes.
"""

from __future__ import annotations

import asyncio
import contextlib
import socket
import sys

from gateway.server.config import GatewayConfig
from gateway.server.logs import configure_logging
from gateway.server.metrics import Metrics
from gateway.server.wire.auth import Authenticator
from gateway.server.wire.connections import ConnectionServer, raise_fd_limit
from gateway.server.wire.session import LinkSession
from gateway.server.wire.tls import server_context
from gateway.server.workers.channel import Op, Outbox, read_batch
from gateway.server.workers.router import Router
from protocol import AnyMessage


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
        self._outbox.put(("o", session.id, session.peer))

    def _received(self, session: LinkSession, message: AnyMessage, received: float) -> None:
        self._outbox.put(("i", session.id, message, received))

    def _closed(self, session: LinkSession) -> None:
        self._by_id.pop(session.id, None)
        self._outbox.put(("x", session.id))

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
            session = self._by_id.get(op[1])
            if session is None:
                continue
            match op[0]:
                case "a":
                    session.send_action(op[2])
                case "m":
                    session.send(op[2], **op[3])
                case "e":
                    session.error(op[2], op[3], op[4])
                case "c":
                    session.close(op[2], op[3])
                case "v":
                    session.version = op[2]

    async def stop(self) -> None:
        """Stop listening and close every connection (1001)."""
        if self._server is not None:
            self._server.close()
            await self._endpoint.close()
        await self.close_links()


async def serve(fd: int) -> None:
    """Run a worker on the channel ``fd`` until the owner's end closes."""
    reader, writer = await asyncio.open_unix_connection(sock=socket.socket(fileno=fd))
    [(_, config, host, port, owner_path)] = await read_batch(reader)
    configure_logging(config.log_level, config.log_format, config.log_file)
    outbox = Outbox(writer)
    worker = Worker(config, outbox)
    await worker.listen(host, port, owner_path)
    outbox.put(("ready",))
    try:
        while True:
            worker.apply(await read_batch(reader))
    except (asyncio.IncompleteReadError, ConnectionError):
        pass  # the owner stopped (or died): so does this worker
    finally:
        await worker.stop()


def main() -> None:
    """Entry point of a worker process."""
    with contextlib.suppress(KeyboardInterrupt):
        asyncio.run(serve(int(sys.argv[1])))


if __name__ == "__main__":
    main()
