"""Schemathesis, the OpenAPI fuzzer, against a live ``fleetgate serve`` in lifelong mode with
authentication: every operation of the document the gateway serves, its stateful links, at
least 1,000 generated requests; no answer is a 5xx, none violates the document (status,
content type, headers, schema), a request without credentials is refused, and the gateway's
log holds no traceback."""

from __future__ import annotations

import json
import re
import secrets
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest

from bench.crash import GatewayProcess, free_port

TOKEN = secrets.token_urlsafe(24)
MIN_REQUESTS = 1000
CONFIG = """
[checks]
use_after_free.enabled = false
positive_data_acceptance.enabled = false

[[operations]]
include-name = "GET /tasks/events"
checks.negative_data_rejection.enabled = false
request-timeout = 0.5
"""
"""Every check Schemathesis has (server errors, status codes, content types, headers, schemas,
refusal of schema-violating requests, of requests without credentials, of undeclared
methods, ...) but two that assume what the API is not: ``use_after_free`` (a cancelled task
is still read, by design: DELETE cancels, it does not erase) and ``positive_data_acceptance``
(a submission valid under the schema may name a wall of the map: 422). On the event stream,
which never ends, each request reads for 0.5 s, and ``negative_data_rejection`` is off: its
only "violation" there is an undeclared header, which HTTP allows."""


@pytest.fixture
def gateway(tmp_path: Path) -> Iterator[GatewayProcess]:
    """``fleetgate serve`` in lifelong mode with a secret operator token (no robots)."""
    gw = GatewayProcess(tmp_path, free_port(), speed=10.0, policy="none")
    gw.config.write_text(json.dumps({
        **json.loads(gw.config.read_text()), "map": None, "autostart": False,
        "tokens": {"operators": [TOKEN]}, "log_level": "INFO",
        "lifelong": {"robots": 3, "warehouse": [2, 3], "task_list": False}}))
    gw.cmd[gw.cmd.index("--log-level") + 1] = "INFO"
    gw.start()
    try:
        yield gw
    finally:
        gw.stop()


def test_schemathesis_finds_no_fault(gateway: GatewayProcess, tmp_path: Path) -> None:
    har = tmp_path / "run.har"
    config = tmp_path / "schemathesis.toml"
    config.write_text(CONFIG)
    url = f"http://127.0.0.1:{gateway.port}"
    run = subprocess.run(
        [str(Path(sys.executable).parent / "schemathesis"), "--config-file", str(config),
         "run", f"{url}/openapi.json", "-H", f"Authorization: Bearer {TOKEN}",
         "--workers", "1", "--max-examples", "100", "--seed", "25", "--no-color",
         "--request-timeout", "5", "--report", "har", "--report-har-path", str(har)],
        capture_output=True, text=True, timeout=300, cwd=tmp_path)
    assert run.returncode == 0, run.stdout[-6000:]
    assert "Selected: 7/7" in run.stdout and "Tested: 7" in run.stdout, run.stdout[-2000:]
    links = re.search(r"API Links:\s+(\d+) covered / (\d+) selected", run.stdout)
    assert links is not None and int(links[1]) >= 4, run.stdout[-3000:]  # the document's 8
    entries = json.loads(har.read_text())["log"]["entries"]
    assert len(entries) >= MIN_REQUESTS, len(entries)
    statuses = [e["response"]["status"] for e in entries]
    assert not [s for s in statuses if s >= 500]
    assert {200, 201, 400, 401, 404, 409} <= set(statuses), set(statuses)
    called = {(e["request"]["method"], e["request"]["url"].removeprefix(url).split("?")[0])
              for e in entries}
    for method, pattern in (("POST", r"/tasks"), ("GET", r"/tasks"), ("GET", r"/tasks/events"),
                            ("GET", r"/tasks/\d+"), ("DELETE", r"/tasks/\d+"),
                            ("POST", r"/tasks/\d+/pause"), ("POST", r"/tasks/\d+/resume")):
        assert any(m == method and re.fullmatch(pattern, p) for m, p in called), pattern
    gateway.log.flush()
    log = gateway.log_path.read_text()
    assert "Traceback" not in log and "ERROR" not in log, log[-2000:]
