"""`fleetgate conformance robot` against both robot implementations: the simulated robots of
`fleetgate sim` (protocol v3, and v2 with ``--protocol 2``) and the real robot_client (its
Kobuki motors simulated on a pty, v3), each started by the checker through --command; and
--url, where the robot is started by someone else."""

from __future__ import annotations

import json
import shlex
import subprocess
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest

from conformance.robot_checks import ROBOT_CHECKS
from gateway.cli import main
from tests.conformance.test_gateway_mode import free_port

HERE = Path(__file__).resolve().parent
SIM = (f"{shlex.quote(sys.executable)} -m gateway sim --connect {{url}} "
       "--robots {robot_id}-{robot_id} --tokens 'conformance-robot-{id}' --world-token none "
       "--reconnect-s 0.2")
KOBUKI = f"{shlex.quote(sys.executable)} {shlex.quote(str(HERE / 'kobuki_robot.py'))} " \
         "{url} {token} {robot_id}"

KNOWN_FAILURES: dict[str, set[str]] = {"sim": set(), "sim-v2": set(), "robot_client": set()}
"""Required checks each robot implementation fails today (compared exactly). Both use the
shared robot session (protocol.robot_session) and pass every required check."""


@pytest.mark.parametrize(("name", "command"), [("sim", SIM), ("sim-v2", f"{SIM} --protocol 2"),
                                               ("robot_client", KOBUKI)])
def test_robot_implementations_pass_every_required_check(
        name: str, command: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    junit = tmp_path / "robot.xml"
    code = main(["conformance", "robot", "--command", command, "--robot-id", "2", "--json",
                 "--junit", str(junit)])
    report = json.loads(capsys.readouterr().out)
    failed = {c["name"]: c["detail"] for c in report["checks"]
              if c["required"] and not c["passed"]}
    assert set(failed) == KNOWN_FAILURES[name], failed
    assert code == (1 if KNOWN_FAILURES[name] else 0)
    assert [c["name"] for c in report["checks"]] == [c.name for c in ROBOT_CHECKS.checks]
    assert ET.parse(junit).getroot().get("tests") == str(len(ROBOT_CHECKS.checks))


def test_listening_on_a_url_for_a_robot_started_elsewhere(
        capsys: pytest.CaptureFixture[str]) -> None:
    url = f"ws://127.0.0.1:{free_port()}/robots"
    robot = subprocess.Popen(shlex.split(SIM.replace("{url}", url).replace("{robot_id}", "0")
                                         .replace("'", "")),
                             stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        code = main(["conformance", "robot", "--url", url, "--only",
                     "robot-presents-its-token,first-message-is-hello,hello-names-the-robot,"
                     "acks-an-action,executes-an-action"])
    finally:
        robot.terminate()
        robot.wait(10)
    out = capsys.readouterr().out
    assert code == 0, out
    assert "CONFORMS: 5 passed" in out


def test_a_robot_command_that_fails_is_a_usage_error(capsys: pytest.CaptureFixture[str]
                                                     ) -> None:
    command = f"{shlex.quote(sys.executable)} -c 'import sys; sys.exit(\"no motors\")' {{url}}"
    assert main(["conformance", "robot", "--command", command, "--timeout", "30"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1
    assert "the robot command exited with code 1 before connecting: no motors" in err
