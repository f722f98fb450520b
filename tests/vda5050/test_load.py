"""``bench/load.py --lifelong --vda5050``: a shift of simulated VDA 5050 vehicles fed through the
task API, against its virtual-time baseline in the same run. Small here (the figures for 200
and 500 vehicles are in docs/vda5050.md): nothing lost or driven twice, no collision, a clean
trace, and errands done as picks and drops."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from sim_clients.mosquitto import MosquittoMissing, find_mosquitto

REPO = Path(__file__).resolve().parents[2]


def _load(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, str(REPO / "bench" / "load.py"), *args],
                          capture_output=True, text=True, timeout=300, cwd=REPO)


def test_lifelong_vda_load_run() -> None:
    try:
        find_mosquitto()
    except MosquittoMissing as exc:
        pytest.skip(str(exc))
    result = _load("--lifelong", "--vda5050", "--robots", "12", "--seconds", "30", "--json")
    assert result.returncode == 0, result.stderr
    out = json.loads(result.stdout.strip().splitlines()[-1])
    # (how many actions and tasks fit in 30 s depends on the machine's load: the planner's
    # first call compiles its kernels; what must hold is that nothing goes wrong)
    assert out["vda5050"] and out["actions"] > 0
    for key in ("lost", "duplicated", "collisions", "trace_errors", "errors"):
        assert out[key] == 0, (key, out)
    assert out["picks_and_drops"] >= out["tasks_network"]  # at least a drop each
    assert out["throughput_ratio"] is not None


def test_vda5050_needs_lifelong() -> None:
    result = _load("--vda5050", "--robots", "2")
    assert result.returncode == 2 and "--lifelong" in result.stderr
    assert "Traceback" not in result.stderr
