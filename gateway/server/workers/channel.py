"""The owner <-> worker channel: a unix socket pair carrying length-prefixed frames, each a
pickled batch (a list of tuples). Both ends trust each other (the pair is created by the
owner and inherited by the worker it starts; nothing else can reach it)."""

from __future__ import annotations

import asyncio
import pickle
import struct
from typing import Any

from gateway.server.per_turn import PerTurn

_HEADER = struct.Struct(">I")

Op = tuple[Any, ...]
"""One event or command: its kind first (see :mod:`~gateway.server.workers.worker`)."""


def frame(ops: list[Op]) -> bytes:
    """The frame of one batch."""
    data = pickle.dumps(ops, protocol=pickle.HIGHEST_PROTOCOL)
    return _HEADER.pack(len(data)) + data


async def read_batch(reader: asyncio.StreamReader) -> list[Op]:
    """The next batch; :class:`asyncio.IncompleteReadError` once the other end is gone."""
    (size,) = _HEADER.unpack(await reader.readexactly(_HEADER.size))
    batch: list[Op] = pickle.loads(await reader.readexactly(size))
    return batch


class Outbox:
    """Ops for the other end, written as ONE frame per event-loop turn (a :class:`PerTurn`)."""

    def __init__(self, writer: asyncio.StreamWriter) -> None:
        self._writer = writer
        self._turn: PerTurn[Op] = PerTurn(self._write)

    def put(self, op: Op) -> None:
        """Queue ``op`` for this turn's frame."""
        self._turn.add(op)

    def _write(self, ops: list[Op]) -> None:
        if not self._writer.is_closing():
            self._writer.write(frame(ops))
