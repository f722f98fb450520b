"""A small HTTP/1.1 client for simulated WMSs, benchmarks and tests: one request per
connection, the request sent as given (method, path, headers, body bytes), the response read
by h11 (the HTTP library uvicorn depends on: no HTTP parsing of our own), server-sent events
split into ``(event, id, data)``."""

from __future__ import annotations

import asyncio
from collections.abc import AsyncGenerator, AsyncIterator

import h11


async def exchange(port: int, method: str, path: str, headers: dict[str, str], body: bytes,
                   host: str = "127.0.0.1") -> AsyncGenerator[h11.Response | bytes, None]:
    """Send one request; yield the response's head, then each piece of its body as it
    comes, until the response ends. ConnectionError if the server closes the connection
    before the response is whole (an OSError, as a reset is)."""
    reader, writer = await asyncio.open_connection(host, port)
    conn = h11.Connection(h11.CLIENT)
    sent = {"Host": f"{host}:{port}", **headers}
    if body or method in ("POST", "PUT", "PATCH"):
        sent["Content-Length"] = str(len(body))
    try:
        writer.write(conn.send(h11.Request(method=method, target=path,
                                           headers=list(sent.items()))) or b"")
        writer.write(conn.send(h11.Data(data=body)) if body else b"")
        writer.write(conn.send(h11.EndOfMessage()) or b"")
        await writer.drain()
        while True:
            try:
                event = conn.next_event()
            except h11.RemoteProtocolError as exc:
                raise ConnectionError(f"{method} {path}: {exc}") from None
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


def head_fields(head: h11.Response) -> dict[str, str]:
    """A response head's headers, names in lower case."""
    return {k.decode().lower(): v.decode("latin-1") for k, v in head.headers}


async def request(port: int, method: str, path: str, headers: dict[str, str],
                  body: bytes = b"", host: str = "127.0.0.1"
                  ) -> tuple[int, dict[str, str], bytes]:
    """One request: the response's status, headers (lower-case names) and body."""
    head: h11.Response | None = None
    content = b""
    async for part in exchange(port, method, path, headers, body, host):
        if isinstance(part, h11.Response):
            head = part
        else:
            content += part
    assert head is not None
    return head.status_code, head_fields(head), content


async def events(parts: AsyncIterator[h11.Response | bytes]
                 ) -> AsyncIterator[tuple[str, str | None, str]]:
    """The server-sent events of a response's body: ``(event, id, data)`` (``event``
    ``message`` when unnamed; events without data are left out)."""
    fields: dict[str, str] = {}
    rest = b""
    async for part in parts:
        if isinstance(part, h11.Response):
            continue
        rest += part
        *lines, rest = rest.split(b"\n")
        for line in lines:
            text = line.decode().rstrip("\r")
            if text:
                name, _, value = text.partition(":")
                fields[name] = value.lstrip(" ")
                continue
            if "data" in fields:
                yield fields.get("event", "message"), fields.get("id"), fields["data"]
            fields = {}
