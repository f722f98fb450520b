"""The VDA 5050 commands as a user runs them: ``fleetgate demo --vda5050`` on a broker,
``fleetgate sim --vda5050`` and ``fleetgate serve`` with a ``[vda5050]`` section; a broker that
cannot be reached or a bad option is one line and exit 2, never a traceback."""

from __future__ import annotations

import json
import socket
from pathlib import Path

from tests.planning.fleetgate_cli import run


def _closed_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


def _one_line_error(result: object, text: str) -> None:
    rc, err = result.returncode, result.stderr  # type: ignore[attr-defined]
    assert rc == 2, err
    assert text in err and "Traceback" not in err, err


def test_demo_runs_vda_vehicles_through_the_broker(broker_url: str) -> None:
    result = run("demo", "--vda5050", "--broker", broker_url, "--headless", "--start", "now",
                 "--speed", "5", "--json", "--port", "0", "--vda-version", "2.0.0")
    assert result.returncode == 0, result.stderr
    summary = json.loads(result.stdout.strip().splitlines()[-1])
    assert summary["collisions"] == 0 and summary["plan_soc"] == 85
    # plan time: at least the plan's SOC of 85 actions of 1 s
    assert summary["soc_ms"] >= 85_000
    assert "10 VDA 5050 vehicles on " + broker_url in result.stderr


def test_unreachable_broker_and_bad_options(tmp_path: Path) -> None:
    url = f"mqtt://127.0.0.1:{_closed_port()}"
    _one_line_error(run("sim", "--vda5050", "--broker", url, "--robots", "2"),
                    f"cannot reach the MQTT broker at {url}")
    config = tmp_path / "gw.toml"
    config.write_text(f'port = 0\n[vda5050]\nbroker = {{ url = "{url}" }}\n'
                      '[[vda5050.vehicles]]\nmanufacturer = "acme"\nserial_number = "a1"\n'
                      'robot_id = 0\n')
    _one_line_error(run("serve", "--config", str(config), "--no-journal"),
                    f"cannot reach the MQTT broker at {url}")
    plain = tmp_path / "plain.toml"
    plain.write_text("port = 0\n")
    _one_line_error(run("sim", "--vda5050", "--config", str(plain)), "no [vda5050] section")
    _one_line_error(run("demo", "--broker", url, "--headless"), "--broker needs --vda5050")
    _one_line_error(run("sim", "--vda5050", "--broker", "http://x"), "--broker")
    bad = tmp_path / "bad.toml"
    bad.write_text('[vda5050]\n[[vda5050.vehicles]]\nmanufacturer = "a/b"\n'
                   'serial_number = "1"\nrobot_id = 0\n')
    _one_line_error(run("serve", "--config", str(bad), "--no-journal"), "manufacturer")
