"""`fleetgate conformance vda5050` plays the master control against vehicles through a real
mosquitto: fleetgate's simulated vehicles (started by the checker through --command, so the
last will is checked too) and the virtual AGV of the npm package vda-5050-lib (an
implementation fleetgate did not write) pass every required check; a deliberately broken
vehicle fails exactly the checks of what it breaks; bad invocations are one line and exit 2."""

from __future__ import annotations

import asyncio
import json
import os
import shlex
import shutil
import sys
from pathlib import Path

import pytest

from conformance.vda5050.checks import VDA_CHECKS, run_vda_checks
from conformance.vda5050.schemas import DEFAULT_DIR, have_schemas
from conformance.vda5050.session import Broker, VdaOptions
from gateway.cli import main
from gateway.vda5050.broker import BrokerConfig
from gateway.vda5050.config import Vda5050Config, VehicleConfig
from sim_clients.vda_fleet import make_vehicles, run_fleet
from sim_clients.vda_vehicle import VdaVehicle

REPO = Path(__file__).resolve().parents[2]
LIB = os.environ.get("FLEETGATE_VDA5050_LIB", "")
SIM = f"{shlex.quote(sys.executable)} -m gateway sim --vda5050 --broker {{broker}} --robots 1"


def _report(capsys: pytest.CaptureFixture[str], *args: str) -> tuple[int, dict[str, bool]]:
    code = main(["conformance", "vda5050", "--json", *args])
    report = json.loads(capsys.readouterr().out)
    return code, {c["name"]: c["passed"] for c in report["checks"]}


def test_simulated_vehicle_passes_every_check(broker_url: str,
                                              capsys: pytest.CaptureFixture[str]) -> None:
    code, passed = _report(capsys, "--broker", broker_url, "--manufacturer", "fleetgate",
                           "--serial", "sim0", "--command", SIM)
    assert list(passed) == [c.name for c in VDA_CHECKS.checks]
    expected = {name: True for name in passed}
    if not have_schemas(DEFAULT_DIR, "2.1.0"):
        expected["schema-valid"] = False  # nothing to validate against
    assert passed == expected
    assert code == (0 if expected["schema-valid"] else 1)


@pytest.mark.skipif(shutil.which("node") is None or not (Path(LIB) / "vda-5050-lib").is_dir(),
                    reason="needs node and FLEETGATE_VDA5050_LIB=<node_modules with "
                           "vda-5050-lib>")
def test_vda_5050_lib_virtual_agv_passes_the_required_checks(
        broker_url: str, capsys: pytest.CaptureFixture[str],
        monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("NODE_PATH", LIB)
    spec = json.dumps({"interface": "uagv", "vehicles": [
        {"manufacturer": "siemens", "serial": "agv1", "mapId": "hall", "x": 2.5, "y": 2.5,
         "theta": 0, "speed": 2}]})
    script = REPO / "tests" / "vda5050" / "external_agvs.js"
    command = f"node {shlex.quote(str(script))} {{broker}} {shlex.quote(spec)}"
    code, passed = _report(capsys, "--broker", broker_url, "--manufacturer", "siemens",
                           "--serial", "agv1", "--version", "2.0.0", "--command", command)
    required = {c.name for c in VDA_CHECKS.checks if c.required}
    if not have_schemas(DEFAULT_DIR, "2.0.0"):
        required.discard("schema-valid")
    assert {n for n in required if not passed[n]} == set()
    assert code == 0 or not have_schemas(DEFAULT_DIR, "2.0.0")
    # what it does not do (it speaks 2.0.0, which has no factsheetRequest; a cancelOrder
    # without an order gets the error but is not listed FAILED) and its last will
    assert (passed["factsheet"], passed["cancel-without-order"], passed["last-will"]) == (
        False, False, True)


class _BrokenVehicle(VdaVehicle):
    """Drives into the horizon (unreleased edges) and ignores startPause."""

    def _maybe_start(self, now_s: float) -> None:
        held = self.held
        held.edges = [e.model_copy(update={"released": True}) for e in held.edges]
        held.nodes = [n.model_copy(update={"released": True}) for n in held.nodes]
        super()._maybe_start(now_s)

    def _instant(self, action_type: str, action_id: str, now_s: float) -> None:
        super()._instant(action_type, action_id, now_s)
        if action_type == "startPause":
            self.paused = False


async def _broken(url: str) -> dict[str, bool]:
    config = Vda5050Config(broker=BrokerConfig(url=url), vehicles=[
        VehicleConfig(manufacturer="acme", serial_number="bad1", robot_id=0)])
    good = make_vehicles(config, None, starts={0: ((3, 3), 0)})[0]
    broken = _BrokenVehicle(good.topics, good.version, good.nodes, good.cell, good.theta)
    stop = asyncio.Event()
    driving = asyncio.create_task(run_fleet([broken], config.broker, stop))
    try:
        results = await run_vda_checks(VdaOptions(broker=Broker(url), manufacturer="acme",
                                                  serial="bad1", timeout_s=8.0))
    finally:
        stop.set()
        await driving
    return {r.name: r.passed for r in results}


def test_a_broken_vehicle_fails_the_checks_of_what_it_breaks(broker_url: str) -> None:
    passed = asyncio.run(_broken(broker_url))
    failed = {name for name, ok in passed.items() if not ok}
    assert {"order-base-horizon", "pause-resume"} <= failed
    assert {"connection-online", "state-request", "factsheet"}.isdisjoint(failed)
    assert "last-will" in failed  # not started by the checker: nothing to kill


def test_bad_invocations(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["conformance", "vda5050", "--broker", "mqtt://127.0.0.1:1"]) == 2
    assert "--manufacturer" in capsys.readouterr().err
    assert main(["conformance", "vda5050", "--broker", "http://x", "--manufacturer", "a",
                 "--serial", "b"]) == 2
    assert "--broker" in capsys.readouterr().err
    assert main(["conformance", "vda5050", "--broker", "mqtt://127.0.0.1:1",
                 "--manufacturer", "a/b", "--serial", "b"]) == 2
    assert "manufacturer" in capsys.readouterr().err
    assert main(["conformance", "vda5050", "--broker", "mqtt://127.0.0.1:1",
                 "--manufacturer", "a", "--serial", "b"]) == 2
    err = capsys.readouterr().err
    assert "cannot reach the MQTT broker" in err and "Traceback" not in err
    assert main(["conformance", "vda5050", "--list"]) == 0
    assert "order-base-horizon" in capsys.readouterr().out
