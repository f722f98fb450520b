"""Configuration sources and precedence, token binding, and ``fleetgate serve`` as a process."""

from __future__ import annotations

import json
import logging
import os
import re
import signal
import subprocess
import sys
import urllib.request
from pathlib import Path

import pytest

from gateway.cli import main
from gateway.server.config import ConfigError, load_config
from gateway.server.logs import JsonFormatter
from gateway.server.wire.auth import Authenticator, AuthError, Peer, request_token

FLEETGATE = str(Path(sys.executable).parent / "fleetgate")


def test_defaults_are_a_loopback_demo() -> None:
    cfg = load_config()
    assert (cfg.host, cfg.port, cfg.map, cfg.policy) == ("127.0.0.1", 8080, "lab", "slack")
    auth = Authenticator(cfg.tokens)
    assert auth.identify("demo-robot-3") == Peer("robot", 3)
    assert auth.identify("demo-operator") == Peer("operator")
    assert auth.identify("demo-world") == Peer("world")


def test_file_env_and_arguments_in_order(tmp_path: Path, monkeypatch: pytest.MonkeyPatch
                                         ) -> None:
    toml = tmp_path / "gw.toml"
    toml.write_text('port = 9000\nthreshold_ms = 1500.0\npolicy = "none"\n'
                    '[tokens]\nrobots = { "s3cret" = 4 }\noperators = ["op-token"]\n'
                    'demo_robot_prefix = ""\n')
    monkeypatch.setenv("FLEETGATE_THRESHOLD_MS", "1750")
    monkeypatch.setenv("FLEETGATE_POLICY", "random")
    cfg = load_config(toml, policy="operator")
    assert cfg.port == 9000  # file
    assert cfg.threshold_ms == 1750.0  # env beats file
    assert cfg.policy == "operator"  # argument beats env
    auth = Authenticator(cfg.tokens)
    assert auth.identify("s3cret") == Peer("robot", 4)
    with pytest.raises(AuthError) as err:
        auth.identify("demo-robot-4")
    assert err.value.status == 403
    js = tmp_path / "gw.json"
    js.write_text(json.dumps({"port": 7000, "autostart": True}))
    assert (load_config(js).port, load_config(js).autostart) == (7000, True)


@pytest.mark.parametrize(("content", "suffix", "message"), [
    ('{"port": "many"}', ".json", "port"),
    ('{"bogus": 1}', ".json", "bogus"),
    ("port = [", ".toml", "cannot read"),
    ("port = 1", ".yaml", ".json or .toml"),
    ('host = "0.0.0.0"', ".toml", "demo tokens"),
])
def test_bad_configuration_is_explained(tmp_path: Path, content: str, suffix: str,
                                        message: str) -> None:
    path = tmp_path / f"c{suffix}"
    path.write_text(content)
    with pytest.raises(ConfigError, match=message):
        load_config(path)


def test_request_token_sources() -> None:
    assert request_token("Bearer abc", "/ws") == "abc"
    assert request_token(None, "/ws?token=xyz&x=1") == "xyz"
    assert request_token("Basic abc", "/ws") is None
    assert request_token(None, "/ws") is None


def test_serve_runs_until_sigterm(tmp_path: Path) -> None:
    cfg = tmp_path / "gw.json"
    cfg.write_text(json.dumps({"port": 0, "log_level": "WARNING"}))
    env = {k: v for k, v in os.environ.items() if "proxy" not in k.lower()}
    proc = subprocess.Popen([FLEETGATE, "serve", "--config", str(cfg)], stderr=subprocess.PIPE,
                            text=True, env=env)
    try:
        assert proc.stderr is not None
        line = proc.stderr.readline()
        assert line.startswith("fleetgate gateway on ws://127.0.0.1:"), line
        port = int(line.split("ws://127.0.0.1:")[1].split("/")[0])
        opener = urllib.request.build_opener(urllib.request.ProxyHandler({}))
        with opener.open(f"http://127.0.0.1:{port}/healthz", timeout=10) as resp:
            assert json.loads(resp.read())["status"] == "ok"
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(timeout=20) == 0
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()


def test_serve_rejects_a_missing_config(tmp_path: Path,
                                        capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["serve", "--config", str(tmp_path / "none.toml")]) == 2
    assert "config file not found" in capsys.readouterr().err


EXAMPLE = Path(__file__).parents[2] / "deploy" / "gateway.example.toml"


def test_the_production_example_refuses_placeholders_and_plaintext(tmp_path: Path) -> None:
    """Issue 27 item 1: as shipped, the example (0.0.0.0, CHANGE-ME tokens, no TLS) does not
    start: one line saying what to change, exit 2."""
    env = {k: v for k, v in os.environ.items() if not k.startswith("FLEETGATE_")}
    run = subprocess.run([FLEETGATE, "serve", "--config", str(EXAMPLE)], env=env,
                         capture_output=True, text=True, timeout=60)
    assert run.returncode == 2
    lines = run.stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in run.stderr, run.stderr
    assert "'0.0.0.0'" in lines[0] and "CHANGE-ME" in lines[0] and "[tls]" in lines[0]
    text = EXAMPLE.read_text()
    real = text.replace("CHANGE-ME-", "f7Kq2-")
    for body, refused in ((real, "[tls]"), ("allow_plaintext = true\n" + text, "CHANGE-ME")):
        path = tmp_path / "gw.toml"
        path.write_text(body)
        with pytest.raises(ConfigError, match=re.escape(refused)) as err:
            load_config(path)
        other = "CHANGE-ME" if refused == "[tls]" else "[tls]"
        assert other not in str(err.value)
    # real tokens behind a TLS proxy: it starts, and only its tokens get in
    path.write_text(real.replace("[tokens]\n", "allow_plaintext = true\n\n[tokens]\n", 1))
    cfg = load_config(path)
    assert cfg.host == "0.0.0.0" and not cfg.allow_demo_tokens
    auth = Authenticator(cfg.tokens)
    assert auth.identify("f7Kq2-robot-2-token") == Peer("robot", 2)
    with pytest.raises(AuthError):
        auth.identify("demo-robot-0")
    # on loopback the placeholders are a harmless local try-out
    assert load_config(EXAMPLE, host="127.0.0.1").tls is None


def test_logs_are_json_lines_with_extra_fields() -> None:
    record = logging.makeLogRecord({"name": "fleetgate.engine", "levelname": "INFO",
                                    "msg": "robot %s connected", "args": (3,), "robot": 3})
    line = json.loads(JsonFormatter().format(record))
    assert line["msg"] == "robot 3 connected" and line["robot"] == 3
    assert line["level"] == "INFO" and line["logger"] == "fleetgate.engine"
