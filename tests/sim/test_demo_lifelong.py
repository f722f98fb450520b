"""``fleetgate demo --lifelong``: a warehouse shift over real websockets on loopback."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

from tracecheck import check_trace, read_trace

FLEETGATE = [sys.executable, "-m", "gateway"]


def test_a_headless_lifelong_demo_runs_a_shift_and_stops(tmp_path: Path) -> None:
    trace = tmp_path / "shift.jsonl"
    proc = subprocess.run(
        [*FLEETGATE, "demo", "--lifelong", "--headless", "--json", "--port", "0",
         "--robots", "8", "--speed", "5", "--seconds", "60", "--motion", "turning",
         "--trace", str(trace)],
        capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    out = json.loads(proc.stdout.strip().splitlines()[-1])
    assert out["robots"] == 8 and out["plan_s"] >= 60.0
    assert out["tasks_finished"] >= 1 and out["tasks_per_min"] > 0
    assert out["lost"] == 0 and out["duplicated"] == 0 and out["collisions"] == 0
    report = check_trace(read_trace(trace))
    assert report.errors == [] and report.collisions == []
    assert "fleetgate demo --lifelong: 8 robots on warehouse" in proc.stderr


def test_lifelong_demo_errors_are_one_line(tmp_path: Path) -> None:
    proc = subprocess.run([*FLEETGATE, "demo", "--lifelong", "--headless", "--port", "0",
                           "--problem", str(tmp_path / "missing.json")],
                          capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2
    assert proc.stderr.strip().splitlines() == [
        f"fleetgate: LoRR problem not found: {tmp_path / 'missing.json'}"]
