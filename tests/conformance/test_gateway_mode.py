"""`fleetgate conformance gateway` against fleetgate's own gateway: a real `fleetgate serve`
subprocess with its embedded defaults on an ephemeral port, and an in-process gateway broken
on purpose, which the checker must catch."""

from __future__ import annotations

import asyncio
import json
import os
import re
import socket
import subprocess
import sys
import threading
import xml.etree.ElementTree as ET
from collections.abc import Iterator
from pathlib import Path

import pytest

from conformance.gateway_checks import GATEWAY_CHECKS
from gateway.cli import main
from gateway.server.config import TlsConfig
from gateway.server.gateway import Gateway
from gateway.server.wire.session import Session
from protocol import AnyMessage, Hello, ProtocolError, decode
from tests.server.conftest import make_config
from tests.server.tls_certs import make_certs

KNOWN_FAILURES: set[str] = set()
"""Required checks fleetgate's gateway fails today, each with the reason (this set is compared
exactly, so the test says when one is fixed)."""


def free_port() -> int:
    """An ephemeral port that was free a moment ago (for a listener started elsewhere)."""
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


@pytest.fixture(scope="module", params=[0, 2], ids=["one-process", "two-workers"])
def served(tmp_path_factory: pytest.TempPathFactory, request: pytest.FixtureRequest
           ) -> Iterator[str]:
    """``fleetgate serve --port 0`` with its embedded defaults, in one process or with two
    worker processes serving the robots (``--workers 2``); its websocket URL. Its state
    directory (the default journal's) is its own: the per-test one of tests/conftest.py is set
    only after module fixtures, and a shared one would resume another run's journal."""
    env = {**os.environ, "XDG_STATE_HOME": str(tmp_path_factory.mktemp("served-state"))}
    env.pop("STATE_DIRECTORY", None)
    proc = subprocess.Popen([sys.executable, "-m", "gateway", "serve", "--port", "0",
                             "--log-level", "WARNING", "--workers", str(request.param)],
                            stderr=subprocess.PIPE, text=True, env=env)
    try:
        assert proc.stderr is not None
        line = proc.stderr.readline()
        found = re.search(r"(ws://127\.0\.0\.1:\d+/ws)", line)
        assert found, f"unexpected first line from fleetgate serve: {line!r}"
        yield found[1]
    finally:
        proc.terminate()
        proc.wait(10)


@pytest.mark.parametrize("robot_version", ["3", "2"])
def test_fleetgate_serve_passes_every_required_check(
        served: str, robot_version: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    junit = tmp_path / "gateway.xml"
    code = main(["conformance", "gateway", served, "--token", "demo-robot-{id}",
                 "--operator-token", "demo-operator", "--robot-version", robot_version,
                 "--json", "--junit", str(junit)])
    report = json.loads(capsys.readouterr().out)
    failed = {c["name"]: c["detail"] for c in report["checks"]
              if c["required"] and not c["passed"]}
    assert set(failed) == KNOWN_FAILURES, failed
    assert code == (1 if KNOWN_FAILURES else 0)
    assert report["passed"] is (not KNOWN_FAILURES)
    assert [c["name"] for c in report["checks"]] == [c.name for c in GATEWAY_CHECKS.checks]
    assert all(set(c) == {"name", "rule", "required", "passed", "detail"}
               for c in report["checks"])
    suite = ET.parse(junit).getroot()
    assert suite.get("tests") == str(len(GATEWAY_CHECKS.checks))
    assert suite.get("failures") == str(len(KNOWN_FAILURES))
    assert {c.get("name") for c in suite.iter("testcase") if c.find("failure") is not None} \
        == KNOWN_FAILURES


class TrustingGateway(Gateway):
    """Broken on purpose: believes the robot id a ``hello`` claims (breaks AUTH-4)."""

    def _admit(self, session: Session, raw: str | bytes) -> AnyMessage | None:
        try:
            message = decode(raw)
        except ProtocolError:
            return super()._admit(session, raw)
        if isinstance(message, Hello) and session.allow():
            return message
        return super()._admit(session, raw)


@pytest.fixture(scope="module")
def broken() -> Iterator[str]:
    """A :class:`TrustingGateway` on 127.0.0.1 in a thread of its own; its URL."""
    ready: list[str] = []
    stop = threading.Event()

    async def serve() -> None:
        async with TrustingGateway(make_config(dispatch_lookahead=1)) as gw:
            ready.append(f"ws://127.0.0.1:{await gw.listen()}/ws")
            while not stop.is_set():
                await asyncio.sleep(0.05)

    thread = threading.Thread(target=asyncio.run, args=(serve(),), daemon=True)
    thread.start()
    while not ready:
        assert thread.is_alive(), "the broken gateway did not start"
        stop.wait(0.05)
    yield ready[0]
    stop.set()
    thread.join(10)


def test_a_gateway_that_trusts_claimed_ids_is_caught(
        broken: str, capsys: pytest.CaptureFixture[str]) -> None:
    code = main(["conformance", "gateway", broken, "--token", "demo-robot-{id}",
                 "--operator-token", "demo-operator", "--json"])
    report = json.loads(capsys.readouterr().out)
    failed = {c["name"] for c in report["checks"] if c["required"] and not c["passed"]}
    assert failed == {"hello-as-another-robot"} | KNOWN_FAILURES
    assert code == 1 and report["passed"] is False
    (check,) = [c for c in report["checks"] if c["name"] == "hello-as-another-robot"]
    assert check["rule"] == "AUTH-4" and "not_yourself" in check["detail"]


@pytest.mark.parametrize(("argv", "message"), [
    (["gateway"], "give the gateway's URL and --token"),
    (["gateway", "http://127.0.0.1:1/ws", "--token", "t"], "expected a ws:// or wss:// URL"),
    (["gateway", "ws://127.0.0.1:1/ws", "--token", "t"], "cannot reach ws://127.0.0.1:1/ws"),
    (["gateway", "ws://127.0.0.1:1/ws", "--token", "t", "--only", "nope"], "unknown check"),
    (["robot"], "give exactly one of --url"),
    (["robot", "--command", "true"], "--command must contain {url}"),
])
def test_bad_invocations_exit_2_with_one_line(argv: list[str], message: str,
                                              capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["conformance", *argv]) == 2
    err = capsys.readouterr().err
    assert message in err and err.count("\n") == 1, err


def test_refused_token_is_a_usage_error(served: str, capsys: pytest.CaptureFixture[str]
                                        ) -> None:
    assert main(["conformance", "gateway", served, "--token", "wrong"]) == 2
    assert "refused --token (HTTP 403)" in capsys.readouterr().err


def test_over_tls_with_a_private_ca(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    certs = make_certs(tmp_path)
    ready: list[int] = []
    stop = threading.Event()

    async def serve() -> None:
        tls = TlsConfig(cert=certs.server_cert, key=certs.server_key)  # robots by token
        async with Gateway(make_config(tls=tls)) as gw:
            ready.append(await gw.listen())
            while not stop.is_set():
                await asyncio.sleep(0.05)

    thread = threading.Thread(target=asyncio.run, args=(serve(),), daemon=True)
    thread.start()
    try:
        while not ready:
            assert thread.is_alive(), "the TLS gateway did not start"
            stop.wait(0.05)
        url = f"wss://127.0.0.1:{ready[0]}/ws"
        args = ["conformance", "gateway", url, "--token", "demo-robot-{id}",
                "--operator-token", "demo-operator", "--only",
                "auth-missing-token-401,hello-gets-welcome,dispatch-fields"]
        code = main([*args, "--cafile", str(certs.ca)])
        assert code == 0, capsys.readouterr()
        assert main(args) == 2  # the private CA is not trusted by default
        assert "cannot" in capsys.readouterr().err
    finally:
        stop.set()
        thread.join(10)
