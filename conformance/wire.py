"""One websocket connection of the checker, either end: typed send, a reader that decodes
strictly and notes every breach of the envelope rules (MSG-1..MSG-3), and waiting for the
first message that matches."""

from __future__ import annotations

import asyncio
import contextlib
import itertools
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, TypeVar

from websockets.asyncio.client import ClientConnection
from websockets.asyncio.server import ServerConnection
from websockets.exceptions import ConnectionClosed

from conformance.report import CheckFailed
from protocol import AnyMessage, Error, ErrorCode, ProtocolError, decode, encode
from protocol.messages import ProtocolVersion

M = TypeVar("M", bound=AnyMessage)

_names = itertools.count(1)


@dataclass
class Breaches:
    """Envelope rule breaches the peer committed, by rule id (seen on every connection)."""

    by_rule: dict[str, list[str]] = field(default_factory=dict)
    messages: int = 0

    def add(self, rule: str, what: str) -> None:
        """Note one breach (the first few of each rule are kept)."""
        found = self.by_rule.setdefault(rule, [])
        if len(found) < 5:
            found.append(what)

    def verdict(self, rule: str) -> None:
        """Raise CheckFailed if ``rule`` was breached."""
        found = self.by_rule.get(rule)
        if found:
            raise CheckFailed("; ".join(found))
        if not self.messages:
            raise CheckFailed("no message was received at all")


class Conn:
    """The checker's end of one connection (a client or a server connection)."""

    def __init__(self, ws: ClientConnection | ServerConnection, breaches: Breaches,
                 name: str = "", ignore: tuple[type[AnyMessage], ...] = ()) -> None:
        self.ws = ws
        self.name = name or f"c{next(_names)}"
        self.breaches = breaches
        self.received: list[AnyMessage] = []
        self._unclaimed: list[AnyMessage] = []
        self._ignore = ignore
        self._seq = itertools.count()
        self._peer_seq = 0
        self._ids: set[str] = set()
        self._changed = asyncio.Event()
        self.closed_code: int | None = None
        self.version: ProtocolVersion | None = None
        """The protocol version of what this end sends (None: the models' default)."""
        self.on_message: Callable[[AnyMessage], None] | None = None
        self._reader = asyncio.get_running_loop().create_task(self._read())

    # ------------------------------------------------------------------ sending
    def next_id(self) -> tuple[str, int]:
        """A fresh ``(msg_id, seq)`` for a message built by hand."""
        seq = next(self._seq)
        return f"{self.name}-{seq}", seq

    async def send(self, kind: type[AnyMessage], **fields: Any) -> str:
        """Send a message of type ``kind``; returns its msg_id."""
        msg_id, seq = self.next_id()
        if self.version is not None:
            fields.setdefault("v", self.version)
        await self.ws.send(encode(kind(msg_id=msg_id, seq=seq, **fields)))
        return msg_id

    async def send_raw(self, data: str | bytes) -> None:
        """Send a frame as is (text for str, binary for bytes)."""
        await self.ws.send(data)

    async def close(self, code: int = 1000) -> None:
        """Close the connection and stop reading."""
        with contextlib.suppress(Exception):
            await asyncio.wait_for(self.ws.close(code), 1.0)
        self._reader.cancel()
        with contextlib.suppress(BaseException):
            await self._reader

    # ------------------------------------------------------------------ receiving
    async def _read(self) -> None:
        try:
            async for raw in self.ws:
                self._take(raw)
        except ConnectionClosed:
            pass
        finally:
            rcvd = self.ws.protocol.close_rcvd
            self.closed_code = rcvd.code if rcvd is not None else 1006
            self._changed.set()

    def _take(self, raw: str | bytes) -> None:
        b = self.breaches
        b.messages += 1
        if isinstance(raw, bytes):
            b.add("WS-1", f"{self.name}: a binary frame")
        try:
            msg = decode(raw)
        except ProtocolError as exc:
            b.add("MSG-1", f"{self.name}: undecodable message ({exc})")
            return
        if msg.seq != self._peer_seq:
            b.add("MSG-2", f"{self.name}: {msg.type} has seq {msg.seq}, expected "
                           f"{self._peer_seq}")
        self._peer_seq = msg.seq + 1
        if msg.msg_id in self._ids:
            b.add("MSG-3", f"{self.name}: msg_id {msg.msg_id!r} used twice")
        self._ids.add(msg.msg_id)
        self.received.append(msg)
        if self.on_message is not None:
            self.on_message(msg)
        if not isinstance(msg, self._ignore):
            self._unclaimed.append(msg)
            self._changed.set()

    def take(self, kind: type[AnyMessage] | tuple[type[AnyMessage], ...] | None = None
             ) -> list[AnyMessage]:
        """Claim every unclaimed message of ``kind`` (all if None), oldest first."""
        taken = [m for m in self._unclaimed if kind is None or isinstance(m, kind)]
        ids = {id(m) for m in taken}
        self._unclaimed[:] = [m for m in self._unclaimed if id(m) not in ids]
        return taken

    async def wait_change(self, timeout: float) -> None:
        """Until a message arrives, the connection closes, or ``timeout`` s pass."""
        self._changed.clear()
        with contextlib.suppress(TimeoutError):
            await asyncio.wait_for(self._changed.wait(), timeout)

    @property
    def is_closed(self) -> bool:
        """True once the connection is closed."""
        return self.closed_code is not None

    async def expect(self, what: str, match: Callable[[AnyMessage], bool],
                     timeout: float = 5.0) -> AnyMessage:
        """The first unclaimed message that ``match`` accepts (claimed now); CheckFailed
        naming ``what`` if none arrives within ``timeout`` s or the connection closes."""
        loop = asyncio.get_running_loop()
        end = loop.time() + timeout
        while True:
            for i, msg in enumerate(self._unclaimed):
                if match(msg):
                    del self._unclaimed[i]
                    return msg
            if self.is_closed:
                raise CheckFailed(f"expected {what}, but the connection closed "
                                  f"(code {self.closed_code}){self._lately()}")
            left = end - loop.time()
            if left <= 0:
                raise CheckFailed(f"no {what} within {timeout:g} s{self._lately()}")
            self._changed.clear()
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(self._changed.wait(), left)

    async def expect_type(self, kind: type[M], timeout: float = 5.0,
                          match: Callable[[M], bool] = lambda m: True,
                          what: str | None = None) -> M:
        """The first unclaimed message of type ``kind`` that ``match`` accepts."""
        msg = await self.expect(what or kind.__name__.lower(),
                                lambda m: isinstance(m, kind) and match(m), timeout)
        assert isinstance(msg, kind)
        return msg

    async def error_for(self, ref: str | None, code: ErrorCode, timeout: float = 5.0) -> Error:
        """The ``error`` replying to ``ref``; CheckFailed unless its code is ``code``."""
        err = await self.expect_type(Error, timeout, lambda e: e.ref == ref,
                                     what=f"error {code.value} with ref {ref!r}")
        if err.code != code:
            raise CheckFailed(f"got error {err.code.value} ({err.detail}), expected "
                              f"{code.value}")
        return err

    async def quiet(self, what: str, match: Callable[[AnyMessage], bool],
                    seconds: float) -> None:
        """CheckFailed if a message that ``match`` accepts arrives within ``seconds``."""
        try:
            msg = await self.expect(what, match, seconds)
        except CheckFailed:
            return
        self._unclaimed.insert(0, msg)  # still there for whoever waits for it
        raise CheckFailed(f"unexpected {what}: {encode(msg)[:200]}")

    async def closed(self, timeout: float = 5.0) -> int:
        """Wait until the peer closes the connection; its close code (as soon as its close
        frame arrived, without waiting for the TCP connection to end)."""
        loop = asyncio.get_running_loop()
        end = loop.time() + timeout
        while self.closed_code is None:
            rcvd = self.ws.protocol.close_rcvd
            if rcvd is not None:
                return rcvd.code
            if loop.time() > end:
                raise CheckFailed(f"the connection was not closed within {timeout:g} s")
            await asyncio.sleep(0.01)
        return self.closed_code

    def _lately(self) -> str:
        if not self._unclaimed:
            return ""
        kinds = ", ".join(m.type for m in self._unclaimed[-5:])
        return f" (unclaimed: {kinds})"
