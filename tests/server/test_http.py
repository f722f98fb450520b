"""HTTP on the gateway's port: Prometheus /metrics, /healthz, static GUI files (traversal-safe).
The gateways run in virtual time: nothing here is about the real clock."""

from __future__ import annotations

import asyncio
import contextlib
import json
from collections.abc import AsyncIterator
from pathlib import Path

import pytest
from prometheus_client.parser import text_string_to_metric_families

from gateway.server.clock import VirtualClock
from gateway.server.gateway import Gateway
from protocol import LoadPlan, Start
from tests.server.conftest import LAB_PATHS, connector, make_config
from tests.server.robots import TestRobot

pytestmark = pytest.mark.looptime  # virtual time over real sockets


async def http_get(port: int, path: str) -> tuple[int, dict[str, str], bytes]:
    """A raw HTTP/1.1 GET (the path is sent exactly as given, no normalisation)."""
    reader, writer = await asyncio.open_connection("127.0.0.1", port)
    writer.write(f"GET {path} HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n".encode())
    await writer.drain()
    head = await reader.readuntil(b"\r\n\r\n")
    lines = head.decode().split("\r\n")
    status = int(lines[0].split()[1])
    headers = {k.lower(): v.strip() for k, v in (ln.split(":", 1) for ln in lines[1:] if ln)}
    body = await reader.readexactly(int(headers["content-length"]))
    writer.close()
    return status, headers, body


@pytest.fixture
def static(tmp_path: Path) -> Path:
    """A static dir holding a tiny GUI (and a secret beside it)."""
    static = tmp_path / "static"
    (static / "js").mkdir(parents=True)
    (static / "index.html").write_text("<html>token={{OPERATOR_TOKEN}}</html>")
    (static / "login.html").write_text("<html>login</html>")
    (static / "js" / "app.js").write_text("console.log(1)")
    (static / "style.css").write_text("body{}")
    (tmp_path / "secret.txt").write_text("do not serve")
    return static


@contextlib.asynccontextmanager
async def served(static: Path | None = None) -> AsyncIterator[tuple[Gateway, int]]:
    """A listening gateway on the test's virtual time serving ``static`` (None: the real
    GUI), and its port."""
    config = make_config() if static is None else make_config(static_dir=static)
    async with Gateway(config, clock=VirtualClock()) as gw:
        await gw.listen()
        yield gw, gw.port or 0


async def test_static_files_with_content_types(static: Path) -> None:
    async with served(static) as (_, port):
        status, headers, body = await http_get(port, "/")
        assert status == 200 and headers["content-type"] == "text/html; charset=utf-8"
        assert body == b"<html>token={{OPERATOR_TOKEN}}</html>"  # served as is: no token
        status, headers, body = await http_get(port, "/js/app.js")
        assert status == 200 and "javascript" in headers["content-type"]
        assert body == b"console.log(1)"
        css = (await http_get(port, "/style.css"))[1]["content-type"]
        assert css == "text/css; charset=utf-8"


@pytest.mark.parametrize("path", ["/../secret.txt", "/%2e%2e/secret.txt", "/js/../../secret.txt",
                                  "/%2E%2E%2Fsecret.txt", "/nothing.html", "/js"])
async def test_paths_outside_or_missing_are_404(static: Path, path: str) -> None:
    async with served(static) as (_, port):
        status, _, body = await http_get(port, path)
    assert status == 404 and b"do not serve" not in body


async def test_healthz(static: Path) -> None:
    async with served(static) as (_, port):
        status, headers, body = await http_get(port, "/healthz")
    assert status == 200 and headers["content-type"] == "application/json"
    assert json.loads(body) == {"status": "ok", "gateway": "empty", "robots": 0}


async def test_metrics_after_a_run(static: Path) -> None:
    async with served(static) as (gw, port):
        await gw.command(LoadPlan(msg_id="l", seq=0, map="lab", paths=LAB_PATHS))
        connect = connector(gw)
        robots = [TestRobot(await connect(f"demo-robot-{i}"), i) for i in range(3)]
        for r in robots:
            await r.hello()
        tasks = [asyncio.create_task(r.run()) for r in robots]
        await gw.command(Start(msg_id="s", seq=1))
        await asyncio.wait_for(gw.wait_done(), 10)
        status, headers, body = await http_get(port, "/metrics")
        for t in tasks:
            t.cancel()
    assert status == 200 and headers["content-type"].startswith("text/plain")
    samples = {s.name: s.value for f in text_string_to_metric_families(body.decode())
               for s in f.samples if not s.labels or "le" not in s.labels}
    # 10 actions in LAB_PATHS (5 + 3 + 2); 7 of them unlocked by a finish
    assert samples["fleetgate_actions_dispatched_total"] == 10
    assert samples["fleetgate_actions_finished_total"] == 10
    assert samples["fleetgate_finish_to_dispatch_seconds_count"] == 7
    assert samples["fleetgate_connected_robots"] == 3
    assert samples["fleetgate_replans_total"] == 0


@pytest.mark.parametrize("path", ["/", "/index.html", "/login", "/login.html", "/app.js",
                                  "/connection.js", "/healthz", "/readyz", "/session",
                                  "/metrics"])
async def test_no_page_holds_the_operator_token(path: str) -> None:
    """The real GUI on a loopback gateway (which used to embed the token in ``/``)."""
    async with served() as (_, port):
        status, _, body = await http_get(port, path)
    assert status in (200, 401) and b"demo-operator" not in body
