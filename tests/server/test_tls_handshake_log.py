"""Failed TLS handshakes are logged (issue 26, defect 9): a client certificate from another
CA and plaintext sent to the TLS port each leave one INFO line with the peer and the reason,
and a flood of them is rate-limited (one line per period, the next counting those left out)."""

from __future__ import annotations

import asyncio
import logging
import ssl
from pathlib import Path

import pytest
from websockets.asyncio.client import connect
from websockets.exceptions import InvalidHandshake

from gateway.server.gateway import Gateway
from gateway.server.wire import tls
from protocol.tls import client_context
from tests.server.conftest import make_config
from tests.server.tls_certs import make_certs


async def _plaintext(port: int) -> None:
    reader, writer = await asyncio.open_connection("127.0.0.1", port)
    writer.write(b"GET /ws HTTP/1.1\r\nHost: x\r\n\r\n")
    await writer.drain()
    await reader.read()  # the gateway closes it
    writer.close()


async def _rogue(port: int, ca: Path, cert: Path) -> None:
    with pytest.raises((ssl.SSLError, OSError, EOFError, InvalidHandshake)):
        async with connect(f"wss://127.0.0.1:{port}/ws", ssl=client_context(ca, cert),
                           proxy=None, open_timeout=5) as ws:
            await ws.recv()


def test_failed_handshakes_are_logged_with_peer_and_reason_rate_limited(
        tmp_path: Path, caplog: pytest.LogCaptureFixture,
        monkeypatch: pytest.MonkeyPatch) -> None:
    certs = make_certs(tmp_path)
    monkeypatch.setattr(tls, "HANDSHAKES", tls.HandshakeLog(period_s=0.0))

    async def main() -> None:
        async with Gateway(make_config(tls=certs.tls(require_client_cert=True))) as gw:
            port = await gw.listen()
            with caplog.at_level(logging.INFO, logger="fleetgate.tls"):
                await _plaintext(port)
                await _rogue(port, certs.ca, certs.rogue)
                await asyncio.sleep(0.2)
                lines = [r for r in caplog.records if r.name == "fleetgate.tls"]
                assert len(lines) == 2, [r.__dict__ for r in lines]
                reasons = [str(getattr(r, "reason", "")) for r in lines]
                assert any("WRONG_VERSION" in x.upper() or "HTTP" in x.upper()
                           for x in reasons), reasons
                assert any("CERTIFICATE" in x.upper() for x in reasons), reasons
                assert all(str(getattr(r, "peer", "")).startswith("127.0.0.1:")
                           for r in lines), [getattr(r, "peer", None) for r in lines]
                caplog.clear()
                tls.HANDSHAKES = limited = tls.HandshakeLog(period_s=60.0)
                for _ in range(5):
                    await _plaintext(port)
                await asyncio.sleep(0.2)
                assert limited.failed == 5
                assert len([r for r in caplog.records if r.name == "fleetgate.tls"]) == 1

    asyncio.run(main())


def test_plain_http_to_the_tls_port_gets_a_400_hint(tmp_path: Path) -> None:
    """Issue 27 item 13: a browser or curl speaking plain HTTP to the TLS port is told to use
    https:// or wss:// (it got an empty reply), and the port keeps serving TLS clients."""
    certs = make_certs(tmp_path)

    async def main() -> tuple[bytes, bytes]:
        async with Gateway(make_config(tls=certs.tls())) as gw:
            port = await gw.listen()
            answers = []
            for request in (b"GET / HTTP/1.1\r\nHost: x\r\n\r\n",
                            b"POST /tasks HTTP/1.1\r\nHost: x\r\nContent-Length: 0\r\n\r\n"):
                reader, writer = await asyncio.open_connection("127.0.0.1", port)
                writer.write(request)
                await writer.drain()
                answers.append(await asyncio.wait_for(reader.read(), 5))
                writer.close()
            # a TLS client still completes its handshake afterwards
            _r, w = await asyncio.open_connection(
                "127.0.0.1", port, ssl=client_context(certs.ca, None),
                server_hostname="127.0.0.1")
            w.close()
            return answers[0], answers[1]

    for answer in asyncio.run(main()):
        head, _, body = answer.partition(b"\r\n\r\n")
        assert head.startswith(b"HTTP/1.1 400 "), answer
        assert b"https://" in body and b"wss://" in body, answer
        assert f"Content-Length: {len(body)}".encode() in head, answer
