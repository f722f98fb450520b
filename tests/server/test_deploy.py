"""deploy/ works: the unit's ExecStart line, run (without systemd) with the TLS example config
on an ephemeral port and certificates from deploy/make-ca.sh, serves its probes over TLS,
refuses a robot presenting another robot's certificate, and executes a short simulated run
whose robots connect over mutual TLS (``fleetgate sim --ca --cert --key``)."""

from __future__ import annotations

import json
import os
import re
import shlex
import shutil
import signal
import ssl
import subprocess
import sys
import time
import urllib.request
from pathlib import Path

import pytest
from websockets.exceptions import InvalidStatus
from websockets.sync.client import connect

ROOT = Path(__file__).resolve().parents[2]
DEPLOY = ROOT / "deploy"
BIN = Path(sys.executable).parent
CREDENTIALS = "/run/credentials/fleetgate.service/"


def service_settings() -> dict[str, list[str]]:
    """``key -> values`` of the unit's [Service] section."""
    settings: dict[str, list[str]] = {}
    section = ""
    for line in (DEPLOY / "fleetgate.service").read_text().splitlines():
        line = line.strip()
        if line.startswith("["):
            section = line
        elif section == "[Service]" and "=" in line and not line.startswith("#"):
            key, _, value = line.partition("=")
            settings.setdefault(key, []).append(value)
    return settings


def test_the_unit_is_limited_and_hardened() -> None:
    s = service_settings()
    assert int(s["LimitNOFILE"][0]) >= 65536
    for key, value in [("DynamicUser", "yes"), ("NoNewPrivileges", "yes"),
                       ("ProtectSystem", "strict"), ("ProtectHome", "yes"),
                       ("PrivateTmp", "yes"), ("PrivateDevices", "yes"),
                       ("CapabilityBoundingSet", ""), ("RestrictNamespaces", "yes"),
                       ("SystemCallArchitectures", "native"), ("UMask", "0077")]:
        assert s[key] == [value], key
    # the TLS files the example config names are the credentials the unit loads
    example = (DEPLOY / "gateway.tls.example.toml").read_text()
    loaded = {v.split(":", 1)[0] for v in s["LoadCredential"]}
    named = set(re.findall(re.escape(CREDENTIALS) + r"([\w.]+)", example))
    assert named and named == loaded


def _https(port: int, path: str, ca: Path) -> tuple[int, dict[str, object]]:
    context = ssl.create_default_context(cafile=str(ca))
    opener = urllib.request.build_opener(urllib.request.ProxyHandler({}),
                                         urllib.request.HTTPSHandler(context=context))
    with opener.open(f"https://127.0.0.1:{port}{path}", timeout=5) as resp:
        return resp.status, json.load(resp)


@pytest.mark.skipif(shutil.which("openssl") is None, reason="openssl is missing")
def test_the_units_command_serves_tls_and_runs_a_fleet(tmp_path: Path) -> None:
    tls = tmp_path / "tls"
    subprocess.run(["bash", str(DEPLOY / "make-ca.sh"), str(tls), "3", "localhost",
                    "127.0.0.1"], check=True, capture_output=True)
    config = tmp_path / "gateway.toml"
    text = (DEPLOY / "gateway.tls.example.toml").read_text()
    text = text.replace(CREDENTIALS, f"{tls}/").replace("CHANGE-ME-", "smoke-")
    text = text.replace('host = "0.0.0.0"', 'host = "127.0.0.1"').replace("port = 8443",
                                                                         "port = 0")
    config.write_text(text)
    argv = shlex.split(service_settings()["ExecStart"][0])
    assert argv[0] == "/opt/fleetgate/bin/fleetgate" and argv[1] == "serve"
    argv[0] = str(BIN / "fleetgate")
    argv[argv.index("--config") + 1] = str(config)
    env = {k: v for k, v in os.environ.items() if "proxy" not in k.lower()}
    env |= {"FLEETGATE_SPEED": "20", "FLEETGATE_AUTOSTART": "true",
            "FLEETGATE_LOG_LEVEL": "WARNING"}
    gateway = subprocess.Popen(argv, env=env, stderr=subprocess.PIPE, text=True)
    sim = None
    try:
        assert gateway.stderr is not None
        port = 0
        for line in gateway.stderr:
            m = re.search(r"fleetgate gateway on wss://127\.0\.0\.1:(\d+)/ws", line)
            if m:
                port = int(m[1])
                break
        assert port, "the gateway did not start"
        assert _https(port, "/readyz", tls / "ca.pem") == (200, {"ready": True})
        status, health = _https(port, "/healthz", tls / "ca.pem")
        # ready to serve; its configured instance is being planned or is loaded (under load
        # the plan can still be running when the probe answers)
        assert status == 200 and health["gateway"] in ("planning", "loaded")
        # robot 0's token with robot 1's certificate: refused at the handshake
        context = ssl.create_default_context(cafile=str(tls / "ca.pem"))
        context.load_cert_chain(tls / "robot-1.pem", tls / "robot-1.key")
        with pytest.raises(InvalidStatus) as refused:
            connect(f"wss://127.0.0.1:{port}/ws", ssl=context, proxy=None,
                    additional_headers={"Authorization": "Bearer smoke-robot-0-token"})
        assert refused.value.response.status_code == 403
        sim = subprocess.Popen(
            [str(BIN / "fleetgate"), "sim", "--connect", f"wss://127.0.0.1:{port}/ws",
             "--robots", "3", "--tokens", "smoke-robot-{id}-token", "--world-token", "none",
             "--ca", str(tls / "ca.pem"), "--cert", str(tls / "robot-{id}.pem"),
             "--key", str(tls / "robot-{id}.key")],
            env=env, stderr=subprocess.DEVNULL)
        deadline = time.monotonic() + 60
        while health["gateway"] != "done" and time.monotonic() < deadline:
            time.sleep(0.2)
            health = _https(port, "/healthz", tls / "ca.pem")[1]
        assert health == {"status": "ok", "gateway": "done", "robots": 3}
    finally:
        for proc in (sim, gateway):
            if proc is not None and proc.poll() is None:
                proc.send_signal(signal.SIGTERM)
        if sim is not None:
            sim.wait(10)
        assert gateway.wait(10) == 0
