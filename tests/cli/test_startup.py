"""The CLI starts at once: building the parser imports no heavy library, and ``--help``
costs a small multiple of a bare interpreter's start (CPU time, best of several runs: a ratio
measured in the same run, never an absolute time)."""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
from pathlib import Path

import pytest

HEAVY = ("numpy", "matplotlib", "pydantic", "dask", "distributed", "rich", "websockets",
         "asyncio", "cv2", "gateway.planning.cbs", "gateway.server.engine",
         "experiments.campaign", "sim_clients.des")
"""Modules that only running a command may import (each costs 0.05 to 1.5 s to import)."""

MAX_HELP_RATIO = 6.0
"""``fleetgate --help`` against ``python -c pass`` (about 3x here; 30x with matplotlib
imported eagerly as before)."""


def _cpu_s(*args: str, env: dict[str, str]) -> float:
    """CPU time of one ``python ARGS`` (its user plus system time)."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    subprocess.run([sys.executable, *args], check=True, capture_output=True, timeout=60, env=env)
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    return (after.ru_utime + after.ru_stime) - (before.ru_utime + before.ru_stime)


def _best_cpu_s(first: list[str], second: list[str], cache: Path, runs: int = 5
                ) -> tuple[float, float]:
    """Best CPU time of ``python FIRST`` and of ``python SECOND`` over ``runs`` each, run in
    turn (a burst of load on a shared machine then charges both alike, not one of them),
    with bytecode cached under ``cache`` (as an installed package has it: with
    PYTHONDONTWRITEBYTECODE set, every run would compile the CLI's modules again and measure
    the compiler, not the imports)."""
    env = {k: v for k, v in os.environ.items() if k != "PYTHONDONTWRITEBYTECODE"}
    env["PYTHONPYCACHEPREFIX"] = str(cache)
    a = b = float("inf")
    for _ in range(runs):
        a = min(a, _cpu_s(*first, env=env))
        b = min(b, _cpu_s(*second, env=env))
    return a, b


def test_building_the_parser_imports_nothing_heavy() -> None:
    code = ("import sys, json; from gateway.cli import build_parser; build_parser(); "
            "print(json.dumps(sorted(sys.modules)))")
    out = subprocess.run([sys.executable, "-c", code], check=True, capture_output=True,
                         text=True, timeout=60).stdout
    loaded = set(json.loads(out))
    assert "experiments.cmd_experiment" in loaded  # the entry point's commands are there
    assert sorted(m for m in loaded if m.split(".")[0] in HEAVY or m in HEAVY) == []


@pytest.mark.parametrize("command", [["--help"], ["simulate", "--help"],
                                     ["experiment", "--help"]])
def test_help_costs_a_small_multiple_of_a_bare_interpreter(command: list[str],
                                                           tmp_path: Path) -> None:
    bare, help_ = _best_cpu_s(["-c", "pass"], ["-m", "gateway", *command], tmp_path)
    assert help_ / bare < MAX_HELP_RATIO, (help_, bare)


def test_python_dash_m_fleetgate_is_the_command() -> None:
    done = subprocess.run([sys.executable, "-m", "fleetgate", "--help"], capture_output=True,
                          text=True, timeout=60, check=False)
    assert done.returncode == 0
    assert done.stdout.startswith("usage: fleetgate ")
    listed = {line.split()[0] for line in done.stdout.splitlines() if line.startswith("    ")}
    assert {"plan", "maps", "serve", "protocol", "simulate", "sim", "demo",
            "experiment"} <= listed


def test_simulate_offers_the_simulators_policies() -> None:
    from gateway.execution.oneshot.policies import AUTONOMOUS_POLICIES
    from sim_clients.cmd_simulate import register

    sub = argparse.ArgumentParser().add_subparsers()
    register(sub)
    (policy,) = [a for a in sub.choices["simulate"]._actions if a.dest == "policy"]
    assert tuple(policy.choices or ()) == AUTONOMOUS_POLICIES  # what SimConfig accepts
