"""The owner <-> worker channel: a unix socket pair carrying length-prefixed frames, each a
batch of records (:mod:`~gateway.server.workers.records`) written with :mod:`marshal`, except
the first, the worker's start (its config, pickled). Both ends trust each other (the pair is
created by the owner and inherited by the worker it starts; nothing else can reach it) and run
the same interpreter (marshal's format is its own)."""

from __future__ import annotations

import asyncio
import marshal
import pickle
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


async def _payload(reader: asyncio.StreamReader) -> bytes:
    (size,) = _HEADER.unpack(await reader.readexactly(_HEADER.size))
    return await reader.readexactly(size)


async def read_batch(reader: asyncio.StreamReader) -> list[Op]:
    """The next batch; :class:`asyncio.IncompleteReadError` once the other end is gone."""
    batch: list[Op] = marshal.loads(await _payload(reader))
    return batch


def start_frame(start: tuple[Any, ...]) -> bytes:
    """The frame of a worker's start (pickled: it carries the config)."""
    return _framed(pickle.dumps(start, protocol=pickle.HIGHEST_PROTOCOL))


async def read_start(reader: asyncio.StreamReader) -> tuple[Any, ...]:
    """A worker's start (:func:`start_frame`)."""
    start: tuple[Any, ...] = pickle.loads(await _payload(reader))
    return start


class Outbox:
    """Ops for the other end, written as ONE frame per event-loop turn (a :class:`PerTurn`),
    or with ``interval_s`` > 0 one frame per interval at most (the :class:`PerTurn`'s).
    ``limit``: once more than that many bytes wait in this process for the other end to read
    them, ``overflow`` is called (and nothing more is written)."""

    def __init__(self, writer: asyncio.StreamWriter, limit: int | None = None,
                 overflow: Callable[[int], None] | None = None, interval_s: float = 0.0
                 ) -> None:
        self._writer = writer
        self._turn: PerTurn[Op] = PerTurn(self._write, interval_s)
        self._limit = limit
        self._overflow = overflow
        self.overflowed = False

    def put(self, op: Op) -> None:
        """Queue ``op`` for this turn's frame."""
        self._turn.add(op)

    def _write(self, ops: list[Op]) -> None:
        writer = self._writer
        if self.overflowed or writer.is_closing():
            return
        writer.write(frame(ops))
        if self._limit is not None:
            waiting = writer.transport.get_write_buffer_size()
            if waiting > self._limit:
                self.overflowed = True
                if self._overflow is not None:
                    self._overflow(waiting)
