"""The owner's side of the workers: starts them on the gateway's port, turns their events
into the engine's queue items, and restarts one that dies (its robots were cut off: each is
``Disconnected``, and they reconnect as after any cut link). A worker that hangs without dying
(it does not answer the ping of every second within ``worker_timeout_s``, or leaves more than
``worker_buffer_bytes`` unread) is killed, and so restarted too. The workers' counts of
protocol errors, refused handshakes and failed handlers are added to the owner's metrics."""

from __future__ import annotations

import asyncio
import contextlib
import logging
import os
import resource
import socket
import sys
from dataclasses import dataclass, field
from pathlib import Path

from gateway.server.clock import Clock
from gateway.server.config import GatewayConfig
from gateway.server.items import (
    Connected,
    Disconnected,
    Inbound,
    Item,
    RobotReport,
    RobotReports,
)
from gateway.server.metrics import Metrics
from gateway.server.wire.auth import Peer
from gateway.server.workers.channel import Channel, Outbox, batch_of, first_done, start_frame
from gateway.server.workers.records import (
    CLOSED,
    COLLECTOR,
    MESSAGE,
    OPENED,
    PING,
    PONG,
    REPORT,
    STATE,
    Op,
    message,
    pose,
)
from gateway.server.workers.remote import RemoteSession

log = logging.getLogger("fleetgate.workers")

START_TIMEOUT_S = 60.0
"""A worker not listening within this is a failed start."""

PING_S = 1.0
"""How often the owner pings each worker."""

_TICK_S = os.sysconf("SC_CLK_TCK")

_ROOT = str(Path(__file__).resolve().parents[3])


def _worker_env() -> dict[str, str]:
    """A worker's environment: it imports this very code (its directory first on the path;
    and ``-P``: not the working directory's, which could hold another version's)."""
    return {**os.environ, "PYTHONPATH": os.pathsep.join(
        p for p in (_ROOT, os.environ.get("PYTHONPATH")) if p)}


@dataclass
class _Handle:
    """One running worker process."""

    index: int
    process: asyncio.subprocess.Process
    channel: Channel
    outbox: Outbox
    sessions: dict[int, RemoteSession] = field(default_factory=dict)
    ready: asyncio.Future[list[Op]] = field(
        default_factory=lambda: asyncio.get_running_loop().create_future())
    """Its first frame (its ready)."""
    ping_at: float | None = None
    """Loop time of its oldest ping not answered yet."""
    counts: dict[str, dict[str, float]] = field(default_factory=dict)
    """Its counts (:meth:`~gateway.server.workers.worker.Worker.counts`) at its last answer."""
    killed: bool = False
    """Killed because it hung (it is ending)."""


def _reserve(host: str, port: int) -> tuple[list[socket.socket], int]:
    """Bind (without listening) ``host:port`` with ``SO_REUSEPORT`` on each of its addresses:
    the port stays the gateway's while workers come and go (a socket that does not listen
    gets no connections). Returns the sockets and the port (chosen here if 0)."""
    held: list[socket.socket] = []
    try:
        for family, kind, proto, _, addr in socket.getaddrinfo(
                host, port, type=socket.SOCK_STREAM, flags=socket.AI_PASSIVE):
            s = socket.socket(family, kind, proto)
            held.append(s)
            s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEPORT, 1)
            s.bind((addr[0], port, *addr[2:]))
            port = s.getsockname()[1]
    except BaseException:
        for s in held:
            s.close()
        raise
    return held, port


class WorkerPool:
    """``count`` worker processes serving the robots on one port for the owner's engine."""

    def __init__(self, config: GatewayConfig, queue: asyncio.Queue[Item], clock: Clock,
                 metrics: Metrics) -> None:
        self._config = config
        self._queue = queue
        self._clock = clock
        self._metrics = metrics
        self._handles: dict[int, _Handle] = {}
        self._tasks: set[asyncio.Task[None]] = set()
        self._reserved: list[socket.socket] = []
        self._stopping = False
        self.collector_paused = False
        """Whether the workers' cyclic collectors are paused (a one-shot run goes on)."""
        self.restarts = 0
        """Workers started again after one died."""
        self.hangs = 0
        """Workers killed because they hung."""

    @property
    def pids(self) -> list[int]:
        """The process ids of the running workers."""
        return [h.process.pid for h in self._handles.values()]

    async def start(self, host: str, port: int, owner_path: str) -> int:
        """Start the workers on ``host:port`` (relaying to ``owner_path``); the port. OSError
        if it cannot be bound, RuntimeError if a worker does not start."""
        self._reserved, port = _reserve(host, port)
        self._where = (host, port, owner_path)
        await asyncio.gather(*(self._start(i) for i in range(self._config.workers)))
        watch = asyncio.get_running_loop().create_task(self._watch(), name="workers-watch")
        self._tasks.add(watch)
        watch.add_done_callback(self._tasks.discard)
        return port

    async def _start(self, index: int) -> None:
        ours, theirs = socket.socketpair(socket.AF_UNIX, socket.SOCK_STREAM)
        try:
            process = await asyncio.create_subprocess_exec(
                sys.executable, "-P", "-m", "gateway.server.workers.worker",
                str(theirs.fileno()), pass_fds=(theirs.fileno(),), env=_worker_env(),
                start_new_session=True)  # no terminal Ctrl-C
        finally:
            theirs.close()
        try:
            channel = await Channel.connect(ours, lambda payload: self._received(handle, payload))
            outbox = Outbox(channel.transport, self._config.worker_buffer_bytes,
                            lambda n: self._hung(handle, f"{n} bytes unread"))
            handle = _Handle(index, process, channel, outbox)
            channel.transport.write(start_frame(("start", self._config, *self._where)))
            async with asyncio.timeout(START_TIMEOUT_S):
                await first_done(handle.ready, channel.closed)
            if not handle.ready.done():
                raise ConnectionError("the channel closed")
        except BaseException as exc:  # no worker is left behind by a failed or cancelled start
            with contextlib.suppress(ProcessLookupError):
                process.kill()
            await asyncio.shield(process.wait())
            if isinstance(exc, TimeoutError | ConnectionError):
                raise RuntimeError(f"worker {index} did not start (exit "
                                   f"{process.returncode})") from None
            raise
        assert handle.ready.result() == [("ready",)], handle.ready.result()
        self._handles[index] = handle
        if self.collector_paused:  # a worker started again during a one-shot run
            handle.outbox.put((COLLECTOR, True))
        task = asyncio.get_running_loop().create_task(self._serve(handle),
                                                      name=f"worker-{index}")
        self._tasks.add(task)
        task.add_done_callback(self._tasks.discard)

    def _received(self, handle: _Handle, payload: memoryview) -> None:
        """A frame from a worker: its first is its ready, the rest its events."""
        ops = batch_of(payload)
        if handle.ready.done():
            self._deliver(handle, ops)
        else:
            handle.ready.set_result(ops)

    async def _serve(self, handle: _Handle) -> None:
        """Once a worker's channel closes (its events were delivered as they arrived, by
        :attr:`Channel.received`): its robots are disconnected; restart it (unless
        stopping)."""
        try:
            await handle.channel.closed
        finally:
            for session in handle.sessions.values():
                session.closing = True
                self._queue.put_nowait(Disconnected(session))
            handle.sessions.clear()
            handle.channel.transport.close()
            self._handles.pop(handle.index, None)
        code = await handle.process.wait()
        delay = 0.1
        while not self._stopping:
            log.warning("worker %d ended (exit %s): restarting it", handle.index, code)
            try:
                await self._start(handle.index)
            except (RuntimeError, OSError) as exc:
                log.error("worker %d: %s", handle.index, exc)
                await asyncio.sleep(delay)
                delay = min(5.0, 2 * delay)
                continue
            self.restarts += 1
            return

    def _deliver(self, handle: _Handle, ops: list[Op]) -> None:
        """A worker's batch as engine queue items (its messages arrive at this plan time):
        each run of robot reports and states as ONE item (:class:`RobotReports`)."""
        now_ms = self._clock.now_ms()
        put = self._queue.put_nowait
        sessions = handle.sessions
        reports: list[RobotReport] = []
        for op in ops:
            code = op[0]
            if code == REPORT:
                _, sid, received, kind, ref, aid, x, y, heading = op
                reports.append((sessions[sid], kind, aid, ref, pose(x, y, heading), received))
                continue
            if code == STATE:
                _, sid, received, x, y, heading = op
                reports.append((sessions[sid], "state", "", "", pose(x, y, heading), received))
                continue
            if reports:
                put(RobotReports(reports, now_ms))
                reports = []
            if code == MESSAGE:
                put(Inbound(sessions[op[1]], message(op), op[2], now_ms))
            elif code == OPENED:
                session = sessions[op[1]] = RemoteSession(handle.outbox, op[1],
                                                          Peer(op[2], op[3]))
                put(Connected(session))
            elif code == CLOSED:
                gone = sessions.pop(op[1])
                gone.closing = True
                put(Disconnected(gone))
            elif code == PONG:
                handle.ping_at = None
                self._count(handle, op[1])
        if reports:
            put(RobotReports(reports, now_ms))

    def hold(self, on: bool) -> None:
        """Leave the workers' frames unread (``on``), or read them again (an
        :attr:`Engine.holding <gateway.server.engine.Engine.holding>` hook: within a loop turn
        of the release, what they sent meanwhile is delivered)."""
        for handle in self._handles.values():
            if on:
                handle.channel.transport.pause_reading()
            else:
                handle.channel.transport.resume_reading()

    def pause_collectors(self, paused: bool) -> None:
        """Pause the workers' cyclic collectors for a one-shot run (``paused``), or give them
        their rare passes back once it is complete (:mod:`~gateway.server.gc_tuning`); a
        worker started meanwhile is told too."""
        self.collector_paused = paused
        for handle in self._handles.values():
            handle.outbox.put((COLLECTOR, paused))

    def flush(self) -> None:
        """Write the owner's commands to each worker now (an :attr:`Engine.after_commit
        <gateway.server.engine.Engine.after_commit>` hook: they are durable)."""
        for handle in self._handles.values():
            handle.outbox.flush()

    def _count(self, handle: _Handle, counts: dict[str, dict[str, float]]) -> None:
        """Add what a worker counted since its last answer to the owner's metrics."""
        metrics = self._metrics
        for name, by_label in counts.items():
            before = handle.counts.get(name, {})
            for label, total in by_label.items():
                more = total - before.get(label, 0.0)
                if more > 0:
                    counter = getattr(metrics, name)
                    (counter.labels(label) if label else counter).inc(more)
        handle.counts = counts

    async def _watch(self) -> None:
        """Ping every worker each :data:`PING_S` (once it answered the last ping); kill one
        whose answer is more than ``worker_timeout_s`` late."""
        loop = asyncio.get_running_loop()
        while True:
            await asyncio.sleep(PING_S)
            now = loop.time()
            for handle in list(self._handles.values()):
                if handle.ping_at is None:
                    handle.ping_at = now
                    handle.outbox.put((PING,))
                elif now - handle.ping_at > self._config.worker_timeout_s:
                    self._hung(handle, f"no answer for {now - handle.ping_at:.1f} s")

    def _hung(self, handle: _Handle, why: str) -> None:
        """Kill a worker that hangs: it ends, and is restarted as one that died."""
        if handle.killed or handle.process.returncode is not None:
            return
        log.error("worker %d hangs (%s): killing it", handle.index, why)
        handle.killed = True
        self.hangs += 1
        with contextlib.suppress(ProcessLookupError):
            handle.process.kill()

    def cpu_s(self) -> float:
        """CPU seconds of the workers: those running now plus those that ended (and any
        other child process of the gateway that ended)."""
        total = 0.0
        for pid in self.pids:
            with contextlib.suppress(OSError, IndexError, ValueError):
                with open(f"/proc/{pid}/stat") as f:
                    fields = f.read().rsplit(")", 1)[1].split()
                total += (int(fields[11]) + int(fields[12])) / _TICK_S
        ended = resource.getrusage(resource.RUSAGE_CHILDREN)
        return total + ended.ru_utime + ended.ru_stime

    async def stop(self) -> None:
        """End the workers (each closes its connections with 1001 when its channel closes)."""
        self._stopping = True
        for handle in list(self._handles.values()):
            handle.channel.transport.close()
        processes = [h.process for h in self._handles.values()]
        if processes:
            _, late = await asyncio.wait([asyncio.ensure_future(p.wait())
                                          for p in processes], timeout=5.0)
            for p in processes:
                if p.returncode is None:
                    with contextlib.suppress(ProcessLookupError):
                        p.kill()
            await asyncio.gather(*late, return_exceptions=True)
        for task in list(self._tasks):
            task.cancel()
        await asyncio.gather(*self._tasks, return_exceptions=True)
        for s in self._reserved:
            s.close()
