"""A raw HTTP/1.1 client for the task API tests (requests sent exactly as given) and a
server-sent events reader."""

from __future__ import annotations

import asyncio
import json
from collections.abc import AsyncIterator
from dataclasses import dataclass
from typing import Any

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


def _request(method: str, path: str, headers: dict[str, str], body: bytes) -> bytes:
    lines = [f"{method} {path} HTTP/1.1", "Host: 127.0.0.1",
             *(f"{k}: {v}" for k, v in headers.items())]
    if body or method in ("POST", "PUT"):
        lines.append(f"Content-Length: {len(body)}")
    return ("\r\n".join(lines) + "\r\n\r\n").encode() + body


async def _head(reader: asyncio.StreamReader) -> tuple[int, dict[str, str]]:
    head = await reader.readuntil(b"\r\n\r\n")
    lines = head.decode("latin-1").split("\r\n")
    status = int(lines[0].split()[1])
    headers = {k.lower(): v.strip() for k, v in (ln.split(":", 1) for ln in lines[1:] if ln)}
    return status, headers


async def call(port: int, method: str, path: str, data: Any = None,
               headers: dict[str, str] | None = None, raw: bytes | None = None) -> Reply:
    """One request (operator credentials unless ``headers`` say otherwise)."""
    hdrs = dict(OPERATOR if headers is None else headers)
    body = raw if raw is not None else (b"" if data is None else json.dumps(data).encode())
    if data is not None:
        hdrs.setdefault("Content-Type", "application/json")
    reader, writer = await asyncio.open_connection("127.0.0.1", port)
    try:
        writer.write(_request(method, path, hdrs, body))
        await writer.drain()
        status, got = await _head(reader)
        length = got.get("content-length")
        content = await (reader.readexactly(int(length)) if length is not None
                         else reader.read())
        return Reply(status, got, content)
    finally:
        writer.close()


@dataclass
class Sse:
    """One server-sent event."""

    event: str
    id: int | None
    data: Any


async def sse(port: int, path: str = "/tasks/events", headers: dict[str, str] | None = None
              ) -> AsyncIterator[Sse]:
    """The events of a stream (with operator credentials) until the server closes it."""
    reader, writer = await asyncio.open_connection("127.0.0.1", port)
    try:
        writer.write(_request("GET", path, {**OPERATOR, **(headers or {})}, b""))
        await writer.drain()
        status, got = await _head(reader)
        assert status == 200 and got["content-type"] == "text/event-stream", (status, got)
        fields: dict[str, str] = {}
        while line := await reader.readline():
            text = line.decode().rstrip("\n")
            if text:
                name, _, value = text.partition(":")
                fields[name] = value.lstrip(" ")
                continue
            if "data" in fields:
                yield Sse(fields.get("event", "message"),
                          int(fields["id"]) if "id" in fields else None,
                          json.loads(fields["data"]))
            fields = {}
    finally:
        writer.close()
