"""The task API tests' client: requests sent as given (method, path, headers, body bytes)
through :mod:`sim_clients.http_client`, and a server-sent events reader."""

from __future__ import annotations

import json
from collections.abc import AsyncIterator
from dataclasses import dataclass
from typing import Any

import h11

from sim_clients.http_client import events, exchange, head_fields, request

OPERATOR = {"Authorization": "Bearer demo-operator"}


@dataclass
class Reply:
    """A response: status, headers (lower-case names) and body."""

    status: int
    headers: dict[str, str]
    body: bytes

    def json(self) -> Any:
        """The body as JSON."""
        return json.loads(self.body)


async def call(port: int, method: str, path: str, data: Any = None,
               headers: dict[str, str] | None = None, raw: bytes | None = None) -> Reply:
    """One request (operator credentials unless ``headers`` say otherwise)."""
    hdrs = dict(OPERATOR if headers is None else headers)
    body = raw if raw is not None else (b"" if data is None else json.dumps(data).encode())
    if data is not None:
        hdrs.setdefault("Content-Type", "application/json")
    return Reply(*await request(port, method, path, hdrs, body))


@dataclass
class Sse:
    """One server-sent event."""

    event: str
    id: int | None
    data: Any


async def sse(port: int, path: str = "/tasks/events", headers: dict[str, str] | None = None
              ) -> AsyncIterator[Sse]:
    """The events of a stream (with operator credentials) until the server closes it."""
    parts = exchange(port, "GET", path, {**OPERATOR, **(headers or {})}, b"")
    head = await anext(parts)
    assert isinstance(head, h11.Response)
    got = head_fields(head)
    assert head.status_code == 200 and got["content-type"] == "text/event-stream", (
        head.status_code, got)
    try:
        async for kind, ident, data in events(parts):
            yield Sse(kind, None if ident is None else int(ident), json.loads(data))
    finally:
        await parts.aclose()
