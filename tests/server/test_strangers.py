"""What a stranger (or a misbehaving client) can make the gateway's HTTP side spend, against
real gateways on 127.0.0.1: a control character or a bare line feed in a header is a 400 and
forges no log line; half-sent bodies without credentials leave memory where it was (they are
refused on their head, never read); bytes sent into an event stream are not piled up; a
dropped event stream frees its slot at once; a trickled head or body ends in bounded time.

The memory figures are the gateway process's resident set (``VmRSS``), scaled down from the
issue's 2,500 connections to 1,000. The same scenarios against the hand-written HTTP reader
(main at 2267e1d, run as ``fleetgate serve``): +84 MB for the half bodies (each
answered 408 after 10 s), +1,225 MB in 3 s for the bytes sent into an event stream."""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from bench.crash import GatewayProcess, free_port
from gateway.server.gateway import Gateway
from gateway.server.task_api.api import MAX_STREAMS
from gateway.server.task_api.models import MAX_BODY_BYTES
from tests.server.conftest import make_config
from tests.server.test_task_api import lifelong_config

TOKEN = "strangers-operator"
MB = 1024 * 1024


def rss(pid: int) -> int:
    """The resident set of process ``pid`` in bytes."""
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) * 1024
    raise AssertionError("no VmRSS")


@pytest.fixture
def served(tmp_path: Path) -> Iterator[GatewayProcess]:
    """``fleetgate serve`` in lifelong mode (no robots) with an operator token."""
    gw = GatewayProcess(tmp_path, free_port(), speed=10.0, policy="none")
    gw.config.write_text(json.dumps({
        **json.loads(gw.config.read_text()), "map": None, "autostart": False,
        "tokens": {"operators": [TOKEN]},
        "lifelong": {"robots": 3, "warehouse": [2, 3], "task_list": False}}))
    gw.start()
    try:
        yield gw
    finally:
        gw.stop()


def _status(answer: bytes) -> int:
    return int(answer.split(b" ", 2)[1]) if answer.startswith(b"HTTP/1.1 ") else 0


HEADS = [
    b"GET /healthz HTTP/1.1\r\nHost: a\r\nX-A: a\x01b\r\n\r\n",
    b"GET /healthz HTTP/1.1\r\nHost: a\r\nX-A: a\x7fb\r\n\r\n",
    b"GET /healthz HTTP/1.1\r\nHost: a\r\nX-A: a\rb\r\n\r\n",
    b"GET /tasks HTTP/1.1\r\nHost: a\r\nX-A: a\nINFO fleetgate.http: operator token accepted\r\n"
    b"\r\n",
    b"GET /ws HTTP/1.1\r\nHost: a\r\nUpgrade: websocket\r\nConnection: Upgrade\r\n"
    b"Sec-WebSocket-Version: 13\r\nSec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\n"
    b"Authorization: Bearer demo-robot-0\nINFO fleetgate.gateway: operator token accepted\r\n"
    b"\r\n",
    b"GET / HTTP/1.1\nHost: a\n\n",
]


@pytest.mark.parametrize("head", HEADS, ids=["ctrl-01", "del", "bare-cr", "bare-lf-api",
                                             "bare-lf-upgrade", "bare-lf-everywhere"])
async def test_a_control_character_or_bare_lf_in_a_header_is_400(
        head: bytes, caplog: pytest.LogCaptureFixture) -> None:
    async with Gateway(make_config()) as gw:
        port = await gw.listen()
        reader, writer = await asyncio.open_connection("127.0.0.1", port)
        writer.write(head)
        async with asyncio.timeout(5):
            answer = await reader.read()
        writer.close()
    assert _status(answer) == 400, answer[:200]
    assert not [r for r in caplog.records if r.levelno >= logging.ERROR]
    assert not [r for r in caplog.records if "token accepted" in r.getMessage()]


def test_the_text_log_escapes_what_a_stranger_sent() -> None:
    from gateway.server.logs import TextFormatter

    record = logging.makeLogRecord({"name": "fleetgate.http", "levelno": logging.WARNING,
                                    "levelname": "WARNING", "msg": "refused %s",
                                    "args": ("a\nINFO fleetgate: operator token accepted",),
                                    "why": "x\r\ny"})
    line = TextFormatter().format(record)
    assert "\n" not in line and "\r" not in line
    assert "a\\x0aINFO fleetgate: operator token accepted" in line and "why=x\\x0d\\x0ay" in line


async def _half_bodies(port: int, n: int) -> list[int]:
    """``n`` connections each sending a ``POST /tasks`` head for a 256 KiB body without
    credentials, then half the body; the statuses they got (0: none)."""
    head = (f"POST /tasks HTTP/1.1\r\nHost: a\r\nContent-Type: application/json\r\n"
            f"Content-Length: {MAX_BODY_BYTES}\r\n\r\n").encode()
    half = b" " * (MAX_BODY_BYTES // 2)
    opened = []
    for _ in range(n):
        reader, writer = await asyncio.open_connection("127.0.0.1", port)
        writer.write(head + half)
        opened.append((reader, writer))

    async def answer(reader: asyncio.StreamReader) -> int:
        try:
            async with asyncio.timeout(20):
                return _status(await reader.read(64))
        except OSError:
            return 0
        except TimeoutError:
            return -1

    statuses = await asyncio.gather(*(answer(r) for r, _ in opened))
    for _, writer in opened:
        writer.transport.abort()
    return list(statuses)


def test_half_bodies_without_credentials_cost_bounded_memory(served: GatewayProcess) -> None:
    """1,000 connections, each sending half of a 256 KiB ``POST /tasks`` body without
    credentials: each is refused on its head at once (401, or 503 past the cap of
    unauthenticated connections; or the refusal was lost to the reset of a connection closed
    with the rest of its body unread: 0), none is left waiting; the gateway's memory stays
    within +40 MB (before: +84 MB here, +908 MB at 2,500 connections) and it still
    answers."""
    assert served.proc is not None
    pid = served.proc.pid
    before = rss(pid)
    statuses = asyncio.run(_half_bodies(served.port, 1000))
    during = rss(pid)
    assert set(statuses) <= {0, 401, 503} and 401 in statuses, \
        sorted((s, statuses.count(s)) for s in set(statuses))
    assert during - before < 40 * MB, (before // MB, during // MB)
    assert served.health()["status"] == "ok"


async def _flood_stream(port: int, payload: bytes, seconds: float) -> tuple[int, bool]:
    """An authenticated event stream whose client keeps sending ``payload``: bytes it got
    sent in, and whether the gateway closed the stream."""
    reader, writer = await asyncio.open_connection("127.0.0.1", port)
    writer.write(f"GET /tasks/events HTTP/1.1\r\nHost: a\r\nAuthorization: Bearer {TOKEN}\r\n"
                 "\r\n".encode())
    assert (await reader.readline()).startswith(b"HTTP/1.1 200")
    sent, end = 0, time.monotonic() + seconds
    try:
        while time.monotonic() < end:
            writer.write(payload)
            async with asyncio.timeout(max(0.01, end - time.monotonic())):
                await writer.drain()
            sent += len(payload)
    except (OSError, TimeoutError):
        pass
    closed = writer.transport.is_closing() or reader.at_eof()
    writer.transport.abort()
    return sent, closed


@pytest.mark.parametrize("payload", [b"garbage " * 8192,
                                     b"GET /healthz HTTP/1.1\r\nHost: a\r\n\r\n" * 2000],
                         ids=["garbage", "pipelined-requests"])
def test_bytes_sent_into_an_event_stream_are_not_piled_up(served: GatewayProcess,
                                                         payload: bytes) -> None:
    """An authenticated client keeps sending into ``GET /tasks/events`` for 3 s (before:
    +1,225 MB): it is cut off or its bytes are not read; the gateway's memory stays within
    +60 MB."""
    assert served.proc is not None
    before = rss(served.proc.pid)
    sent, _ = asyncio.run(_flood_stream(served.port, payload, 3.0))
    after = rss(served.proc.pid)
    assert after - before < 60 * MB, (sent // MB, before // MB, after // MB)
    assert served.health()["status"] == "ok"


async def test_a_dropped_event_stream_frees_its_slot_at_once() -> None:
    async with Gateway(lifelong_config()) as gw:
        port = await gw.listen()
        head = (b"GET /tasks/events HTTP/1.1\r\nHost: a\r\n"
                b"Authorization: Bearer demo-operator\r\n\r\n")
        streams = []
        for _ in range(MAX_STREAMS):
            reader, writer = await asyncio.open_connection("127.0.0.1", port)
            writer.write(head)
            assert (await reader.readline()).startswith(b"HTTP/1.1 200")
            streams.append(writer)
        reader, writer = await asyncio.open_connection("127.0.0.1", port)
        writer.write(head)
        assert (await reader.readline()).startswith(b"HTTP/1.1 503")
        writer.close()
        streams.pop().transport.abort()  # a WMS that went away
        dropped = time.monotonic()
        while True:
            reader, writer = await asyncio.open_connection("127.0.0.1", port)
            writer.write(head)
            status = await reader.readline()
            writer.transport.abort()
            if status.startswith(b"HTTP/1.1 200"):
                break
            assert time.monotonic() - dropped < 1.0, status
            await asyncio.sleep(0.05)
        for w in streams:
            w.transport.abort()


async def test_a_trickled_head_or_body_ends_in_bounded_time() -> None:
    """A head trickled a byte every 0.2 s is cut off after the handshake timeout (1 s here);
    an authenticated body trickled likewise is answered 408."""
    async with Gateway(lifelong_config(handshake_timeout_s=1.0)) as gw:
        port = await gw.listen()

        async def trickle(first: bytes, then: bytes) -> tuple[bytes, float]:
            reader, writer = await asyncio.open_connection("127.0.0.1", port)
            writer.write(first)
            t0 = time.monotonic()
            answer = b""
            with contextlib.suppress(OSError):
                for byte in then:  # a byte, then 0.2 s of listening
                    writer.write(bytes([byte]))
                    with contextlib.suppress(TimeoutError):
                        async with asyncio.timeout(0.2):
                            answer = await reader.read(4096)
                    if answer or reader.at_eof():
                        break
            writer.transport.abort()
            return answer, time.monotonic() - t0

        answer, took = await trickle(b"GET /healthz HTTP/1.1\r\n", b"Host: a\r\n" * 10)
        assert answer == b"" and took < 3.0
        answer, took = await trickle(
            b"POST /tasks HTTP/1.1\r\nHost: a\r\nAuthorization: Bearer demo-operator\r\n"
            b"Content-Type: application/json\r\nContent-Length: 100\r\n\r\n", b" " * 50)
        assert _status(answer) == 408 and took < 3.0, answer[:200]
