"""The auth matrix: who may connect and what they may send, over real TLS with mutual TLS
(trustme certificates), as one table. Each row opens a real ``wss://`` connection (or tries
to) to one gateway on 127.0.0.1 and records what happened."""

from __future__ import annotations

import asyncio
import ssl
from dataclasses import dataclass
from pathlib import Path

from websockets.asyncio.client import ClientConnection, connect
from websockets.exceptions import InvalidHandshake, InvalidStatus

from gateway.server.config import TokensConfig
from gateway.server.gateway import Gateway
from protocol import AnyMessage, Error, Hello, IntruderReport, Start, Welcome, decode, encode
from tests.server.conftest import make_config
from tests.server.tls_certs import Certs, make_certs

TOKENS = TokensConfig(robots={"tok-r0": 0, "tok-r1": 1}, operators=["tok-op"],
                      world=["tok-world"], demo_robot_prefix=None)


@dataclass(frozen=True)
class Row:
    """One attempt: credentials, then a message to send (None: just listen)."""

    token: str | None
    cert: int | str | None = None
    """Client certificate: a robot id, "rogue" (another CA) or None."""
    send: AnyMessage | None = None
    origin: str | None = None
    login: bool = False
    """Authenticate with the GUI's login cookie (obtained with ``token``) instead."""
    scheme: str = "wss"


def _hello(robot: int) -> Hello:
    return Hello(msg_id="m", seq=0, robot_id=robot)


START = Start(msg_id="m", seq=0)
OWN = "https://127.0.0.1:{port}"

MATRIX: dict[str, tuple[Row, str]] = {
    "no credentials": (Row(None), "http 401"),
    "wrong token": (Row("tok-nope"), "http 403"),
    "robot token and its certificate": (Row("tok-r0", 0, _hello(0)), "welcome"),
    "robot certificate alone": (Row(None, 1, _hello(1)), "welcome"),
    "robot token without a client certificate": (Row("tok-r0", None, _hello(0)), "http 403"),
    "robot token with another robot's certificate": (Row("tok-r0", 1, _hello(0)), "http 403"),
    "certificate from another CA": (Row("tok-r0", "rogue", _hello(0)), "refused"),
    "plain ws:// on the TLS port": (Row("tok-r0", 0, _hello(0), scheme="ws"), "http 400"),
    "robot claims another robot's id": (Row("tok-r0", 0, _hello(1)), "error not_yourself"),
    "robot sends an operator command": (Row("tok-r0", 0, START), "error forbidden"),
    "world sends an operator command": (Row("tok-world", None, START), "error forbidden"),
    "world says hello as a robot": (Row("tok-world", None, _hello(0)), "error forbidden"),
    "operator reports an intruder": (
        Row("tok-op", None, IntruderReport(msg_id="m", seq=0, cell=(0, 0), state="on")),
        "error forbidden"),
    "operator token": (Row("tok-op"), "snapshot"),
    "operator token, own Origin": (Row("tok-op", origin=OWN), "snapshot"),
    "operator token, foreign Origin": (Row("tok-op", origin="https://evil.example"),
                                       "http 403"),
    "GUI login cookie, own Origin": (Row("tok-op", origin=OWN, login=True), "snapshot"),
    "GUI login cookie, foreign Origin": (Row("tok-op", origin="https://evil.example",
                                             login=True), "http 403"),
    "GUI login with a robot token": (Row("tok-r0", login=True), "login 403"),
    "GUI login with a wrong token": (Row("tok-nope", login=True), "login 403"),
}


async def _login(port: int, context: ssl.SSLContext, token: str) -> tuple[int, str]:
    """``GET /session`` with a bearer token: (status, Set-Cookie header)."""
    reader, writer = await asyncio.open_connection("127.0.0.1", port, ssl=context,
                                                   server_hostname="127.0.0.1")
    writer.write(f"GET /session HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\n"
                 f"Authorization: Bearer {token}\r\n\r\n".encode())
    await writer.drain()
    head = (await reader.readuntil(b"\r\n\r\n")).decode()
    writer.close()
    lines = head.split("\r\n")
    cookie = next((ln.split(":", 1)[1].strip() for ln in lines
                   if ln.lower().startswith("set-cookie:")), "")
    return int(lines[0].split()[1]), cookie


async def _attempt(port: int, certs: Certs, row: Row) -> str:
    cert = row.cert if isinstance(row.cert, int) else None
    context = certs.client(cert, rogue=row.cert == "rogue")
    headers: dict[str, str] = {}
    if row.login:
        assert row.token is not None
        status, cookie = await _login(port, certs.client(), row.token)
        if status != 204:
            return f"login {status}"
        assert "HttpOnly" in cookie and "SameSite=Strict" in cookie and "Secure" in cookie
        headers["Cookie"] = cookie.split(";")[0]
    elif row.token is not None:
        headers["Authorization"] = f"Bearer {row.token}"
    origin = row.origin.format(port=port) if row.origin else None
    try:
        ws: ClientConnection = await connect(
            f"{row.scheme}://127.0.0.1:{port}/ws", ssl=context if row.scheme == "wss" else None,
            additional_headers=headers, origin=origin, proxy=None,  # type: ignore[arg-type]
            open_timeout=5)
    except InvalidStatus as exc:
        return f"http {exc.response.status_code}"
    except (OSError, InvalidHandshake, EOFError, TimeoutError):
        return "refused"
    async with ws:
        try:
            if row.send is not None:
                await ws.send(encode(row.send))
            async with asyncio.timeout(5):
                while True:
                    reply = decode(await ws.recv())
                    if isinstance(reply, Welcome):
                        return "welcome"
                    if isinstance(reply, Error):
                        return f"error {reply.code.value}"
                    if reply.type == "snapshot" and row.send is None:
                        return "snapshot"
        except (OSError, InvalidHandshake, EOFError) as exc:  # TLS 1.3: refused after "open"
            return f"refused ({type(exc).__name__})"


async def test_auth_matrix(tmp_path: Path) -> None:
    certs = make_certs(tmp_path)
    config = make_config(tls=certs.tls(), tokens=TOKENS)
    async with Gateway(config) as gw:
        port = await gw.listen()
        outcomes = {name: await _attempt(port, certs, row) for name, (row, _) in MATRIX.items()}
    assert outcomes == {name: expected for name, (_, expected) in MATRIX.items()}
    assert len(MATRIX) == 20


async def test_robot_client_settings_speak_mutual_tls(tmp_path: Path) -> None:
    from robot_client.config import load_settings

    certs = make_certs(tmp_path)
    async with Gateway(make_config(tls=certs.tls(), tokens=TOKENS)) as gw:
        port = await gw.listen()
        settings = load_settings(None, gateway_url=f"wss://127.0.0.1:{port}/ws", robot_id=1,
                                 token="tok-r1", grid_width=4, grid_height=4,
                                 ca_file=certs.ca, client_cert=certs.robots[1])
        context = settings.ssl_context()
        assert context is not None
        async with connect(settings.gateway_url, ssl=context, proxy=None,
                           additional_headers={"Authorization": "Bearer tok-r1"}) as ws:
            await ws.send(encode(_hello(1)))
            assert isinstance(decode(await ws.recv()), Welcome)
        plain = load_settings(None, gateway_url="ws://127.0.0.1:1/ws", robot_id=1, token="t",
                              grid_width=4, grid_height=4)
        assert plain.ssl_context() is None
