"""When a connection of the gateway's HTTP server reads (``GatewayHttpProtocol`` with uvicorn's
own config and server state, over a real socket pair): not past a request's head until the
application asks for the body (a stranger's body is not read before its credentials are
checked), and without pausing at all for a request read whole."""

from __future__ import annotations

import asyncio
import socket

from starlette.types import Receive, Scope, Send
from uvicorn import Config
from uvicorn.server import ServerState

from gateway.server.wire.asgi_server import GatewayHttpProtocol

HEAD = (b"POST /tasks HTTP/1.1\r\nHost: x\r\nContent-Type: application/json\r\n"
        b"Content-Length: 8\r\n\r\n")


async def exchange(parts: list[bytes]) -> tuple[list[bool], bytes]:
    """Send ``parts`` one by one to an application that waits before it reads the body;
    whether the connection was reading after each part, and the answer (the body's
    length)."""
    asked = asyncio.Event()

    async def app(scope: Scope, receive: Receive, send: Send) -> None:
        await asked.wait()
        body = b""
        while True:
            message = await receive()
            body += message.get("body", b"")
            if not message.get("more_body"):
                break
        await send({"type": "http.response.start", "status": 200,
                    "headers": [(b"content-length", b"1")]})
        await send({"type": "http.response.body", "body": str(len(body)).encode()})

    config = Config(app, http=GatewayHttpProtocol, lifespan="off", log_config=None)
    config.load()
    ours, theirs = socket.socketpair()
    loop = asyncio.get_running_loop()
    protocol = GatewayHttpProtocol(config=config, server_state=ServerState(), app_state={})
    transport, _ = await loop.connect_accepted_socket(lambda: protocol, ours)
    reader, writer = await asyncio.open_connection(sock=theirs)
    reading = []
    for part in parts:
        writer.write(part)
        await writer.drain()
        for _ in range(20):  # let the server read and parse it
            await asyncio.sleep(0.005)
        reading.append(transport.is_reading())
    asked.set()
    answer = await asyncio.wait_for(reader.read(1000), 10)
    writer.close()
    transport.close()
    return reading, answer.rsplit(b"\r\n", 1)[-1]


async def test_a_body_is_not_read_before_the_application_asks_for_it() -> None:
    reading, body = await exchange([HEAD + b"{\"a\"", b":12}"])
    assert reading == [False, False]  # paused with the head in, not resumed by more bytes
    assert body == b"8"  # the body was read whole once asked for


async def test_a_request_read_whole_leaves_reading_on() -> None:
    reading, body = await exchange([HEAD + b"{\"a\":12}"])
    assert reading == [True]
    assert body == b"8"
