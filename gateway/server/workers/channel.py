"""The owner <-> worker channel: a unix socket pair carrying length-prefixed frames, each a
batch of records (:mod:`~gateway.server.workers.records`) written with :mod:`marshal`, except
the first, the worker's start (its config, pickled). Both ends trust each other (the pair is
created by the owner and inherited by the worker it starts; nothing else can reach it) and run
the same interpreter (marshal's format is its own)."""

from __future__ import annotations

import asyncio
import marshal
import pickle
import socket
import struct
from collections.abc import Callable
from typing import Any

from gateway.server.per_turn import PerTurn
from gateway.server.workers.records import Op

_HEADER = struct.Struct(">I")


def _framed(data: bytes) -> bytes:
    return _HEADER.pack(len(data)) + data


def frame(ops: list[Op]) -> bytes:
    """The frame of one batch."""
    return _framed(marshal.dumps(ops))


def start_frame(start: tuple[Any, ...]) -> bytes:
    """The frame of a worker's start (pickled: it carries the config)."""
    return _framed(pickle.dumps(start, protocol=pickle.HIGHEST_PROTOCOL))


def batch_of(payload: bytes | memoryview) -> list[Op]:
    """The batch of a frame's payload."""
    ops: list[Op] = marshal.loads(payload)
    return ops


def start_of(payload: bytes | memoryview) -> tuple[Any, ...]:
    """The worker's start of a :func:`start_frame`'s payload."""
    loaded: tuple[Any, ...] = pickle.loads(payload)
    return loaded


async def first_done(*futures: asyncio.Future[Any]) -> None:
    """Wait until one of ``futures`` is done (a frame expected, or the channel closed)."""
    await asyncio.wait(futures, return_when=asyncio.FIRST_COMPLETED)


class Channel(asyncio.Protocol):
    """One end of the channel as a protocol: the payload of each whole frame goes to
    ``received`` as its bytes arrive (several frames of one read in one call each, no task
    woken and no await per frame); ``closed`` is done once the other end is gone.
    ``received`` may be replaced between frames (a start, then batches)."""

    transport: asyncio.Transport
    """Its transport (to write to the other end)."""

    def __init__(self, received: Callable[[memoryview], None]) -> None:
        self.received = received
        self.closed: asyncio.Future[None] = asyncio.get_running_loop().create_future()
        self._pending = b""  # the start of a frame not whole yet

    @classmethod
    async def connect(cls, sock: socket.socket, received: Callable[[memoryview], None]
                      ) -> Channel:
        """The channel on ``sock``, this process's end of the socket pair."""
        transport, channel = await asyncio.get_running_loop().create_unix_connection(
            lambda: cls(received), sock=sock)
        channel.transport = transport  # (not from connection_made: uvloop calls it later)
        return channel

    def data_received(self, data: bytes) -> None:
        """Hand over every frame now whole; keep the rest."""
        if self._pending:
            data = self._pending + data
        view = memoryview(data)
        at, end = 0, len(data)
        while end - at >= _HEADER.size:
            (size,) = _HEADER.unpack_from(view, at)
            stop = at + _HEADER.size + size
            if stop > end:
                break
            self.received(view[at + _HEADER.size:stop])
            at = stop
        self._pending = data[at:]

    def connection_lost(self, exc: Exception | None) -> None:
        """The other end is gone (or this one closed)."""
        if not self.closed.done():
            self.closed.set_result(None)


class Outbox:
    """Ops for the other end, written as ONE frame per event-loop turn (a :class:`PerTurn`),
    or with ``interval_s`` > 0 one frame per interval at most (the :class:`PerTurn`'s).
    ``limit``: once more than that many bytes wait in this process for the other end to read
    them, ``overflow`` is called (and nothing more is written)."""

    def __init__(self, transport: asyncio.Transport, limit: int | None = None,
                 overflow: Callable[[int], None] | None = None, interval_s: float = 0.0
                 ) -> None:
        self._transport = transport
        self._turn: PerTurn[Op] = PerTurn(self._write, interval_s)
        self._limit = limit
        self._overflow = overflow
        self.overflowed = False

    def put(self, op: Op) -> None:
        """Queue ``op`` for this turn's frame."""
        self._turn.add(op)

    def flush(self) -> None:
        """Write this turn's frame now."""
        self._turn.flush()

    def _write(self, ops: list[Op]) -> None:
        transport = self._transport
        if self.overflowed or transport.is_closing():
            return
        transport.write(frame(ops))
        if self._limit is not None:
            waiting = transport.get_write_buffer_size()
            if waiting > self._limit:
                self.overflowed = True
                if self._overflow is not None:
                    self._overflow(waiting)
