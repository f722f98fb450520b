"""Every subcommand, driven with bad input as a user types it: one line saying what is wrong
(or the subcommand's own usage for a mistyped option), a documented exit code, never a
traceback. A real ``fleetgate`` subprocess each time."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

DOCUMENTED_EXIT_CODES = {0, 2, 3, 130}
LAB = ["--map", "lab", "--scen", "lab-random-1"]

# (id, arguments with {tmp} for a scratch folder, expected exit code, text expected on stderr)
CASES: list[tuple[str, list[str], int, str]] = [
    ("plan-mistyped-option", ["plan", *LAB, "--agnets", "3"], 2,
     "fleetgate plan: error: unrecognized arguments: --agnets 3"),
    ("plan-missing-map-file", ["plan", "--map", "{tmp}/none.map", "--scen", "lab-random-1"], 2,
     "does not exist"),
    ("plan-missing-map-path", ["plan", "--map", "missing.map", "--scen", "lab-random-1"], 2,
     "map file 'missing.map' does not exist"),
    ("plan-missing-scen", ["plan", "--map", "lab", "--scen", "{tmp}/none.scen"], 2,
     "does not exist"),
    ("plan-malformed-map", ["plan", "--map", "{tmp}/bad.map", "--scen", "lab-random-1"], 2,
     "bad.map"),
    ("plan-binary-scen", ["plan", "--map", "lab", "--scen", "{tmp}/binary.scen"], 2,
     "binary.scen"),
    ("plan-too-many-agents", ["plan", *LAB, "--agents", "500"], 2, "500"),
    ("plan-zero-agents", ["plan", *LAB, "--agents", "0"], 2, "--agents"),
    ("plan-negative-time", ["plan", *LAB, "--time-limit", "-1"], 2, "--time-limit"),
    ("plan-no-instance", ["plan"], 2, "--map and --scen"),
    ("maps-mistyped-option", ["maps", "list", "--jsn"], 2, "fleetgate maps list: error"),
    ("maps-generate-unwritable", ["maps", "generate", "random", "x", "--out",
                                  "{tmp}/file.txt/sub"], 2, "cannot write"),
    ("maps-generate-bad-size", ["maps", "generate", "random", "x", "--width", "0", "--out",
                                "{tmp}"], 2, ""),
    ("maps-download-unreachable", ["maps", "download", "x", "--base-url",
                                   "http://127.0.0.1:9/", "--timeout", "5"], 2, "failed"),
    ("protocol-unwritable", ["protocol", "schema", "-o", "{tmp}/no/such/dir/p.json"], 2,
     "cannot write"),
    ("serve-missing-config", ["serve", "--config", "{tmp}/none.toml"], 2, "not found"),
    ("serve-not-toml", ["serve", "--config", "{tmp}/bad.toml"], 2, "bad.toml"),
    ("serve-yaml-config", ["serve", "--config", "{tmp}/g.yaml"], 2, ".json or .toml"),
    ("serve-unknown-key", ["serve", "--config", "{tmp}/unknown.toml"], 2, "colour"),
    ("serve-map-without-agents", ["serve", "--config", "{tmp}/maponly.toml"], 2,
     "needs scen or agents"),
    ("serve-demo-tokens-public", ["serve", "--host", "0.0.0.0"], 2,
     'demo_robot_prefix = ""'),
    ("serve-bad-port", ["serve", "--port", "99999"], 2, "port"),
    ("serve-missing-scen", ["serve", "--config", "{tmp}/noscen.toml"], 2, "none.scen"),
    ("simulate-mistyped-option", ["simulate", *LAB, "--polcy", "slack"], 2,
     "fleetgate simulate: error"),
    ("simulate-bad-solver-time", ["simulate", *LAB, "--solver-time", "soon"], 2,
     "fleetgate simulate: error: argument --solver-time"),
    ("simulate-too-many-agents", ["simulate", *LAB, "--agents", "500"], 2, "500"),
    ("simulate-unwritable-trace", ["simulate", *LAB, "--agents", "2", "--trace",
                                   "{tmp}/no/dir/t.jsonl"], 2, "cannot write the trace"),
    ("simulate-bad-fallback", ["simulate", *LAB, "--fallback", "0"], 2, "--fallback"),
    ("sim-bad-robots", ["sim", "--robots", "a-b"], 2, "robots"),
    ("sim-bad-url", ["sim", "--connect", "http://127.0.0.1:1/"], 2, "--connect"),
    ("sim-missing-tokens", ["sim", "--tokens", "{tmp}/none.json"], 2, "--tokens"),
    ("demo-too-many-agents", ["demo", "--headless", "--agents", "500"], 2, "500"),
    ("demo-bad-speed", ["demo", "--speed", "0"], 2, "--speed"),
    ("demo-bad-port", ["demo", "--headless", "--agents", "2", "--port", "99999"], 2, "port"),
    ("demo-unwritable-log", ["demo", "--headless", "--agents", "2", "--port", "0",
                             "--log-file", "{tmp}/no/dir/x.log"], 2, "log file"),
    ("demo-negative-replans", ["demo", "--max-replans", "-1"], 2, "--max-replans"),
    ("demo-mistyped-option", ["demo", "--headles", "--port", "0"], 2, "fleetgate demo: error"),
    ("experiment-too-many-agents", ["experiment", "--maps", "lab", "--agents", "500",
                                    "--instances", "1", "--seeds", "1", "--out", "{tmp}/e",
                                    "--no-progress"], 2, "500"),
    ("experiment-unknown-map", ["experiment", "--maps", "{tmp}/none.map", "--agents", "2",
                                "--instances", "1", "--seeds", "1", "--out", "{tmp}/e"], 2,
     "does not exist"),
    ("experiment-bad-agents", ["experiment", "--maps", "lab", "--agents", "x", "--out",
                               "{tmp}/e"], 2, "--agents"),
    ("experiment-no-scheduler", ["experiment", "--maps", "lab", "--agents", "2", "--instances",
                                 "1", "--seeds", "1", "--out", "{tmp}/e", "--no-progress",
                                 "--scheduler", "tcp://127.0.0.1:9"], 2, "scheduler"),
    ("experiment-missing-out", ["experiment", "--maps", "lab"], 2,
     "fleetgate experiment: error"),
    ("experiment-sample-without-oracle", ["experiment", "--maps", "lab", "--agents", "2",
                                          "--instances", "1", "--seeds", "1", "--out",
                                          "{tmp}/e", "--oracle-sample", "3"], 2,
     "--oracle-sample needs --oracle"),
    ("experiment-bad-oracle-step", ["experiment", "--maps", "lab", "--agents", "2",
                                    "--instances", "1", "--seeds", "1", "--out", "{tmp}/e",
                                    "--oracle", "--oracle-step-ms", "0"], 2,
     "--oracle-step-ms"),
]


@pytest.fixture(scope="module")
def scratch(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Bad files the cases refer to as {tmp}/NAME."""
    tmp = tmp_path_factory.mktemp("bad")
    (tmp / "bad.map").write_text("type octile\nheight 2\nwidth 2\nmap\n..\n.?\n")
    (tmp / "binary.scen").write_bytes(b"\xff\xfe\x00garbage")
    (tmp / "bad.toml").write_text("port = [1,\n")
    (tmp / "g.yaml").write_text("port: 1\n")
    (tmp / "unknown.toml").write_text("colour = 'blue'\n")
    (tmp / "maponly.toml").write_text("map = 'lab'\n")
    (tmp / "noscen.toml").write_text(f"map = 'lab'\nscen = '{tmp}/none.scen'\n")
    (tmp / "file.txt").write_text("a file, not a folder\n")
    return tmp


@pytest.mark.parametrize(("args", "code", "says"), [c[1:] for c in CASES],
                         ids=[c[0] for c in CASES])
def test_bad_input_gets_one_line_and_a_documented_code(scratch: Path, args: list[str],
                                                       code: int, says: str) -> None:
    argv = [a.replace("{tmp}", str(scratch)) for a in args]
    done = subprocess.run([sys.executable, "-m", "fleetgate", *argv], capture_output=True,
                          text=True, timeout=60, check=False, cwd=scratch,
                          env={**os.environ, "FLEETGATE_MAPS": ""})
    assert "Traceback" not in done.stderr, done.stderr
    assert done.returncode in DOCUMENTED_EXIT_CODES
    assert done.returncode == code, done.stderr
    assert says in done.stderr, done.stderr
    lines = done.stderr.strip().splitlines()
    if " error: " in done.stderr:  # argparse: the subcommand's usage, then the error
        assert lines[0].startswith(f"usage: fleetgate {argv[0]}"), done.stderr
        assert len([ln for ln in lines if " error: " in ln]) == 1
    else:
        assert len(lines) == 1, done.stderr


@pytest.mark.parametrize(("content", "says"), [
    (None, "cannot read"),
    ('{"t_ms": 0, "type": "plan", "plan": 0, "agents": [{"path": [[0, 0]]}]}\n{"t_ms": 1',
     "not JSON"),
    (b"\xff\xfe\x00\x00", "can't decode"),
    ("[1, 2]\n", "must be a JSON object"),
], ids=["missing", "truncated", "binary", "not-objects"])
def test_the_trace_checker_refuses_what_is_not_a_trace(tmp_path: Path, content: str | bytes |
                                                        None, says: str) -> None:
    trace = tmp_path / "t.jsonl"
    if isinstance(content, bytes):
        trace.write_bytes(content)
    elif content is not None:
        trace.write_text(content)
    done = subprocess.run([sys.executable, "-m", "tracecheck", str(trace)], capture_output=True,
                          text=True, timeout=60, check=False)
    assert "Traceback" not in done.stderr, done.stderr
    assert done.returncode == 2 and done.stdout == ""
    assert done.stderr.startswith("tracecheck: ") and says in done.stderr
    assert len(done.stderr.splitlines()) == 1
