"""An HTTP/1.1 client for the task API tests (requests sent as given: method, path, headers
and body bytes; responses read with h11, the HTTP library uvicorn depends on) and a
server-sent events reader."""

from __future__ import annotations

import asyncio
import json
from collections.abc import AsyncIterator
from dataclasses import dataclass
from typing import Any

import h11

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


async def _exchange(port: int, method: str, path: str, headers: dict[str, str], body: bytes
                    ) -> AsyncIterator[h11.Response | bytes]:
    """Send one request; yield the response's head, then each piece of its body."""
    reader, writer = await asyncio.open_connection("127.0.0.1", port)
    conn = h11.Connection(h11.CLIENT)
    sent = {"Host": "127.0.0.1", **headers}
    if body or method in ("POST", "PUT"):
        sent["Content-Length"] = str(len(body))
    try:
        writer.write(conn.send(h11.Request(method=method, target=path,
                                           headers=list(sent.items()))) or b"")
        writer.write(conn.send(h11.Data(data=body)) if body else b"")
        writer.write(conn.send(h11.EndOfMessage()) or b"")
        await writer.drain()
        while True:
            event = conn.next_event()
            if event is h11.NEED_DATA:
                conn.receive_data(await reader.read(65536))
            elif isinstance(event, h11.Response):
                yield event
            elif isinstance(event, h11.Data):
                yield bytes(event.data)
            elif isinstance(event, h11.EndOfMessage | h11.ConnectionClosed):
                return
    finally:
        writer.close()


def _headers(head: h11.Response) -> dict[str, str]:
    return {k.decode().lower(): v.decode("latin-1") for k, v in head.headers}


async def call(port: int, method: str, path: str, data: Any = None,
               headers: dict[str, str] | None = None, raw: bytes | None = None) -> Reply:
    """One request (operator credentials unless ``headers`` say otherwise)."""
    hdrs = dict(OPERATOR if headers is None else headers)
    body = raw if raw is not None else (b"" if data is None else json.dumps(data).encode())
    if data is not None:
        hdrs.setdefault("Content-Type", "application/json")
    head: h11.Response | None = None
    content = b""
    async for part in _exchange(port, method, path, hdrs, body):
        if isinstance(part, h11.Response):
            head = part
        else:
            content += part
    assert head is not None
    return Reply(head.status_code, _headers(head), content)


@dataclass
class Sse:
    """One server-sent event."""

    event: str
    id: int | None
    data: Any


async def sse(port: int, path: str = "/tasks/events", headers: dict[str, str] | None = None
              ) -> AsyncIterator[Sse]:
    """The events of a stream (with operator credentials) until the server closes it."""
    fields: dict[str, str] = {}
    rest = b""
    async for part in _exchange(port, "GET", path, {**OPERATOR, **(headers or {})}, b""):
        if isinstance(part, h11.Response):
            got = _headers(part)
            assert part.status_code == 200 and got["content-type"] == "text/event-stream", (
                part.status_code, got)
            continue
        rest += part
        *lines, rest = rest.split(b"\n")
        for line in lines:
            text = line.decode()
            if text:
                name, _, value = text.partition(":")
                fields[name] = value.lstrip(" ")
                continue
            if "data" in fields:
                yield Sse(fields.get("event", "message"),
                          int(fields["id"]) if "id" in fields else None,
                          json.loads(fields["data"]))
            fields = {}
