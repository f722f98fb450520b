"""Connections on the other cores (``workers = N``, ``fleetgate serve --workers N``).

Worker processes (:mod:`~gateway.server.workers.worker`) share the gateway's port
(``SO_REUSEPORT``: the kernel spreads new connections over them). Each one terminates TLS and
websockets for the robots that land on it, runs their handshake, authentication, rate limit
and message checks (the very code of the one-process gateway,
:class:`~gateway.server.wire.connections.ConnectionServer`), and passes what it admitted to the
owner process in batches (:mod:`~gateway.server.workers.channel`). Everything else (HTTP, the
GUI, operators, the world) it relays byte for byte to the owner's own HTTP server on a private
unix socket (:mod:`~gateway.server.workers.router`).

The owner process (:class:`~gateway.server.workers.pool.WorkerPool`) keeps the engine, the
executor and the journal: it is still their only writer. A robot served by a worker is a
:class:`~gateway.server.workers.remote.RemoteSession` to it, whose messages leave in one batch
per event-loop turn, after the owner task committed the journal (as a local session's writer
task runs only then). A worker that dies is restarted; its robots reconnect, as after any cut
link.
"""
