"""The owner's view of a robot connection that a worker process serves."""

from __future__ import annotations

import pickle
from typing import Any

from gateway.server.wire.auth import Peer
from gateway.server.wire.session import Session
from gateway.server.workers.channel import Outbox
from gateway.server.workers.records import ACTION, CLOSE, ERROR, SEND, VERSION
from protocol import PROTOCOL_VERSION, AnyMessage, ErrorCode, action_body
from protocol.messages import ProtocolVersion


class RemoteSession(Session):
    """A :class:`~gateway.server.wire.session.Session` whose messages are commands to the
    worker that holds the connection (its session ``id`` there): the worker builds them with
    its connection's msg_id/seq, counts errors against its budget and writes them."""

    def __init__(self, outbox: Outbox, sid: int, peer: Peer) -> None:
        self._outbox = outbox
        self.id = sid
        self.peer = peer
        self.closing = False
        self._version: ProtocolVersion = PROTOCOL_VERSION

    @property
    def version(self) -> ProtocolVersion:
        """The protocol version of this connection (a robot's ``hello`` fixes it)."""
        return self._version

    @version.setter
    def version(self, v: ProtocolVersion) -> None:
        if v != self._version:
            self._version = v
            self._outbox.put((VERSION, self.id, v))

    def send(self, kind: type[AnyMessage], **fields: Any) -> None:
        """Have the worker send a ``kind`` message with these fields."""
        if not self.closing:
            self._outbox.put((SEND, self.id, pickle.dumps((kind, fields),
                                                          protocol=pickle.HIGHEST_PROTOCOL)))

    def send_action(self, fields: dict[str, Any]) -> None:
        """Have the worker send an ``action`` with these fields (as its JSON body)."""
        if not self.closing:
            self._outbox.put((ACTION, self.id, action_body(fields)))

    def error(self, code: ErrorCode, ref: str | None, detail: str) -> None:
        """Have the worker reply ``error`` (counted against the connection's budget there)."""
        if not self.closing:
            self._outbox.put((ERROR, self.id, code.value, ref, detail))

    def close(self, code: int = 1000, reason: str = "") -> None:
        """Have the worker flush and close the connection."""
        if not self.closing:
            self.closing = True
            self._outbox.put((CLOSE, self.id, int(code), reason))
