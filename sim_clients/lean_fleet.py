"""Lean simulated robots for load tests: thousands per process, raw websocket frames.

The robots of :mod:`sim_clients.fleet` run the full robot stack (the shared protocol session,
pydantic messages, the websockets client, a simulated world): right for conformance and
demos, but at a thousand robots they cost the machine about as much CPU as the gateway they
load. A :class:`LeanFleet` robot is one :class:`asyncio.Protocol` per connection: it speaks
the HTTP upgrade and RFC 6455 frames itself (client frames masked with a fresh random key each,
through websockets' C ``apply_mask``), parses what arrives with :func:`json.loads` and writes
its few message shapes with f-strings. What it does is what a protocol v3 robot (or, with
``version=2``, a v2 one) must do in a load run: ``hello`` with its start cell; every
``action`` queued (a v2 robot acknowledges it with an ``ack``; a v3 robot's ``started``
does); the queue
executed in order, each action lasting its ``duration_ms`` x U(1-J, 1+J) (a fixed seed per
robot), ``started`` when it begins and ``finished`` when it ends (a ``finished`` and the next
``started`` in one write); a ``state`` every ``state_period_ms`` of the welcome (the first at a
random phase); pings answered. There is no world and no reconnect: the gateway's ADG keeps the
robots apart (its trace is checked by tracecheck), and a dropped link is an error of the run.

A :class:`LeanFleet` is given its robots' plan paths: each connects to
``ws://127.0.0.1:PORT/ws`` as ``demo-robot-r`` and runs until it finished its path's actions
(or the deadline). ``bench/load.py`` runs several such fleets in processes of their own, so the
robots load one gateway from several cores.
"""

from __future__ import annotations

import asyncio
import base64
import gc
import json
import os
import random
import struct
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from websockets.speedups import apply_mask

CONNECTING_AT_ONCE = 200
"""Handshakes a process keeps open at a time (a burst of thousands would run into the
gateway's handshake timeout)."""


@dataclass
class LeanStats:
    """What one process's robots saw (perf_counter seconds: comparable across processes)."""

    received: dict[str, float] = field(default_factory=dict)
    """First arrival of every action id."""
    finish_sent: dict[str, float] = field(default_factory=dict)
    """When each action's ``finished`` was written to its socket."""
    duplicates: int = 0
    errors: list[str] = field(default_factory=list)
    cpu_s: float = 0.0
    """This process's CPU time from the first robot welcomed to the end."""


def frame(text: str) -> bytes:
    """One masked text frame of ``text`` (FIN set), as a client must send it."""
    payload = text.encode()
    n = len(payload)
    mask = random.getrandbits(32).to_bytes(4, "little")
    if n < 126:
        head = bytes((0x81, 0x80 | n))
    elif n < 65536:
        head = struct.pack("!BBH", 0x81, 0xFE, n)
    else:
        head = struct.pack("!BBQ", 0x81, 0xFF, n)
    return head + mask + apply_mask(payload, mask)


def _control(opcode: int, payload: bytes) -> bytes:
    mask = random.getrandbits(32).to_bytes(4, "little")
    return bytes((0x80 | opcode, 0x80 | len(payload))) + mask + apply_mask(payload, mask)


class LeanRobot(asyncio.Protocol):
    """One robot and its connection (see the module docstring for what it does)."""

    def __init__(self, fleet: LeanFleet, robot: int, cell: list[int], actions: int) -> None:
        self.fleet = fleet
        self.v = fleet.version
        self.robot = robot
        self.cell = cell
        self.left = actions
        """Actions still to finish."""
        self.rng = random.Random(f"{fleet.seed}/{robot}")
        self.transport: asyncio.Transport | None = None
        self.upgraded = False
        self.buf = b""
        self.seq = 0
        self.queue: deque[tuple[str, float, list[int]]] = deque()
        self.current: tuple[str, float, list[int]] | None = None
        self.welcomed = asyncio.get_running_loop().create_future()
        self.period_s = 5.0
        self.state_timer: asyncio.TimerHandle | None = None
        self.key = base64.b64encode(os.urandom(16)).decode()

    # ------------------------------------------------------------------ transport
    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        """Send the upgrade request."""
        assert isinstance(transport, asyncio.Transport)
        self.transport = transport
        transport.write(
            f"GET /ws HTTP/1.1\r\nHost: 127.0.0.1:{self.fleet.port}\r\nUpgrade: websocket\r\n"
            f"Connection: Upgrade\r\nSec-WebSocket-Key: {self.key}\r\n"
            f"Sec-WebSocket-Version: 13\r\nAuthorization: Bearer demo-robot-{self.robot}\r\n"
            "\r\n".encode())

    def connection_lost(self, exc: Exception | None) -> None:
        """A link lost before the robot is done is an error of the run."""
        self.transport = None
        if self.state_timer is not None:
            self.state_timer.cancel()
        if not self.welcomed.done():
            self.welcomed.set_exception(ConnectionError(f"robot {self.robot}: link lost"))
        elif self.left > 0 and not self.fleet.stopping:
            self.fleet.stats.errors.append(f"robot {self.robot}: link lost ({exc})")
            self.fleet.robot_done()

    def data_received(self, data: bytes) -> None:
        """Parse the upgrade response, then frames."""
        buf = self.buf + data
        if not self.upgraded:
            end = buf.find(b"\r\n\r\n")
            if end < 0:
                self.buf = buf
                return
            status = buf[:buf.find(b"\r\n")]
            if b" 101 " not in status + b" ":
                self._fail(f"upgrade refused: {status.decode(errors='replace')}")
                return
            self.upgraded = True
            buf = buf[end + 4:]
            self._send(f'{{"type":"hello","v":{self.v},"msg_id":"h","seq":0,"robot_id":{self.robot},'
                       f'"pose":{{"cell":[{self.cell[0]},{self.cell[1]}]}}}}')
        pos, size = 0, len(buf)
        while size - pos >= 2:
            b1 = buf[pos + 1] & 0x7F
            head = 2
            if b1 == 126:
                if size - pos < 4:
                    break
                b1, head = struct.unpack_from("!H", buf, pos + 2)[0], 4
            elif b1 == 127:
                if size - pos < 10:
                    break
                b1, head = struct.unpack_from("!Q", buf, pos + 2)[0], 10
            if size - pos < head + b1:
                break
            opcode = buf[pos] & 0x0F
            payload = buf[pos + head:pos + head + b1]
            pos += head + b1
            if opcode == 1:  # the gateway never fragments its small messages
                self._message(json.loads(payload))
            elif opcode == 9:
                self._write(_control(10, payload))
            elif opcode == 8:
                self._write(_control(8, payload[:2]))
        self.buf = buf[pos:]

    def _fail(self, why: str) -> None:
        if not self.welcomed.done():
            self.welcomed.set_exception(ConnectionError(f"robot {self.robot}: {why}"))
        if self.transport is not None:
            self.transport.close()

    def _write(self, data: bytes) -> None:
        if self.transport is not None:
            self.transport.write(data)

    def _envelope(self, kind: str) -> str:
        self.seq += 1
        return f'{{"type":"{kind}","v":{self.v},"msg_id":"m{self.seq}","seq":{self.seq}'

    def _send(self, text: str) -> None:
        self._write(frame(text))

    # ------------------------------------------------------------------ protocol
    def _message(self, msg: dict[str, Any]) -> None:
        kind = msg["type"]
        if kind == "action":
            self._action(msg)
        elif kind == "welcome":
            self.period_s = msg.get("state_period_ms", 5000.0) / 1000.0
            self.state_timer = asyncio.get_running_loop().call_later(
                self.period_s * self.rng.random(), self._state)
            if not self.welcomed.done():
                self.welcomed.set_result(None)
            for action in msg.get("resend", ()):
                self._action(action)
        elif kind == "error":
            self.fleet.stats.errors.append(f"robot {self.robot}: {msg.get('code')}: "
                                           f"{msg.get('detail')}")
        else:  # cancel, pause, resume: a load run has none
            self.fleet.stats.errors.append(f"robot {self.robot}: unexpected {kind}")

    def _action(self, msg: dict[str, Any]) -> None:
        aid: str = msg["action_id"]
        fleet = self.fleet
        if not fleet.started.done():
            fleet.started.set_result(None)
        stats = fleet.stats
        if aid in stats.received:
            stats.duplicates += 1
        else:
            stats.received[aid] = time.perf_counter()
        duration = msg["duration_ms"] / 1000.0
        jitter = self.fleet.jitter
        if jitter:
            duration *= 1.0 + self.rng.uniform(-jitter, jitter)
        self.queue.append((aid, duration, msg["dst"]["cell"]))
        ack = frame(f'{self._envelope("ack")},"action_id":"{aid}"}}') if self.v < 3 else b""
        if self.current is None:
            self._write(ack + self._start())
        elif ack:
            self._write(ack)

    def _start(self) -> bytes:
        """Begin the next queued action; its ``started`` frame."""
        self.current = aid, duration, _ = self.queue.popleft()
        asyncio.get_running_loop().call_later(duration, self._finish)
        return frame(f'{self._envelope("started")},"action_id":"{aid}"}}')

    def _finish(self) -> None:
        current = self.current
        assert current is not None
        aid, _, self.cell = current
        self.current = None
        data = frame(f'{self._envelope("finished")},"action_id":"{aid}",'
                     f'"pose":{{"cell":[{self.cell[0]},{self.cell[1]}]}}}}')
        if self.queue:
            data += self._start()
        self.fleet.stats.finish_sent[aid] = time.perf_counter()
        self._write(data)
        self.left -= 1
        if self.left == 0:
            self.fleet.robot_done()

    def _state(self) -> None:
        if self.transport is None or self.fleet.stopping:
            return
        activity = "running" if self.current is not None else "idle"
        self._send(f'{self._envelope("state")},"robot_id":{self.robot},'
                   f'"pose":{{"cell":[{self.cell[0]},{self.cell[1]}]}},"activity":"{activity}"}}')
        self.state_timer = asyncio.get_running_loop().call_later(self.period_s, self._state)


def _factory(proto: LeanRobot) -> Callable[[], LeanRobot]:
    return lambda: proto


class LeanFleet:
    """The robots of one process (see the module docstring)."""

    def __init__(self, port: int, paths: dict[int, list[list[int]]], jitter: float,
                 seed: int, version: int = 3) -> None:
        self.port = port
        self.version = version
        """The protocol version the robots speak (2: an ``ack`` per action; 3: none)."""
        self.paths = paths
        self.jitter = jitter
        self.seed = seed
        self.stats = LeanStats()
        self.stopping = False
        self._busy = len(paths)
        self._done = asyncio.get_running_loop().create_future()
        self.started = asyncio.get_running_loop().create_future()
        """Set when the first action arrives (the gateway started the run)."""
        self.robots: list[LeanRobot] = []

    def robot_done(self) -> None:
        """One robot finished its actions (or lost its link)."""
        self._busy -= 1
        if self._busy <= 0 and not self._done.done():
            self._done.set_result(None)

    async def _connect(self, robot: int, path: list[list[int]], gate: asyncio.Semaphore
                       ) -> None:
        loop = asyncio.get_running_loop()
        async with gate:
            for attempt in range(5):
                proto = LeanRobot(self, robot, path[0], len(path) - 1)
                try:
                    await loop.create_connection(_factory(proto), "127.0.0.1", self.port)
                    await proto.welcomed
                except (OSError, ConnectionError) as exc:
                    if attempt == 4:
                        raise ConnectionError(f"robot {robot} cannot connect: {exc}") from None
                    await asyncio.sleep(0.5 * (attempt + 1))
                    continue
                self.robots.append(proto)
                if proto.left == 0:
                    self.robot_done()
                return

    async def run(self, deadline_s: float, start_s: float = 600.0) -> LeanStats:
        """Connect every robot, run until all are done or ``deadline_s`` after the first
        action arrived (at most ``start_s`` after the last robot connected: the gateway starts
        once every robot of every process is there); close the links."""
        gate = asyncio.Semaphore(CONNECTING_AT_ONCE)
        await asyncio.gather(*(self._connect(r, p, gate) for r, p in self.paths.items()))
        gc.freeze()  # the robots live until the end: keep full passes off them
        cpu0 = time.process_time()
        try:
            await asyncio.wait_for(asyncio.shield(self.started), start_s)
            await asyncio.wait_for(asyncio.shield(self._done), deadline_s)
        except TimeoutError:
            self.stats.errors.append(f"deadline: {self._busy} robots not done")
        self.stopping = True
        for _ in range(40):  # up to 2 s for the last reports to leave
            if not any(r.transport is not None and r.transport.get_write_buffer_size()
                       for r in self.robots):
                break
            await asyncio.sleep(0.05)
        for r in self.robots:
            if r.transport is not None:
                r.transport.write(_control(8, struct.pack("!H", 1000)))
                r.transport.close()
        self.stats.cpu_s = time.process_time() - cpu0
        return self.stats
