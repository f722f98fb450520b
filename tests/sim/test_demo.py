"""``fleetgate demo``: gateway + simulated fleet over real websockets on loopback, in real time,
as a user runs it (a subprocess); its trace is checked by the independent trace checker. What
the plan's time is checked against runs in virtual time (the same gateway and fleet in this
process), so it holds at any load."""

from __future__ import annotations

import json
import re
import signal
import subprocess
import sys
import urllib.request
from pathlib import Path

from gateway.execution.params import PAPER
from gateway.planning.instance import Instance, load_instance
from gateway.planning.plan import NeverExpires, Plan
from gateway.planning.solver import solve
from gateway.runtime.mapstore import resolve
from gateway.server.clock import VirtualClock, run_virtual
from gateway.server.config import GatewayConfig
from gateway.server.gateway import Gateway
from gateway.server.planner import Problem
from protocol.messages import PolicyName
from sim_clients.connect import websocket_connector
from sim_clients.demo_instance import DEFAULT_AGENTS, DEFAULT_MAP, DEFAULT_SCEN
from sim_clients.fleet import fleet_for, run_in_process
from sim_clients.summary import RunSummary
from tracecheck import check_trace, read_trace

FLEETGATE = [sys.executable, "-m", "gateway"]


def demo(*args: str, timeout: float = 90.0) -> dict[str, object]:
    """Run ``fleetgate demo --headless --json --port 0 ARGS``; its JSON result."""
    proc = subprocess.run([*FLEETGATE, "demo", "--headless", "--json", "--port", "0", *args],
                          capture_output=True, text=True, timeout=timeout, check=False)
    assert proc.returncode == 0, proc.stderr
    result: dict[str, object] = json.loads(proc.stdout)
    return result


def _demo_plan() -> tuple[Instance, Plan]:
    """The zero-setup demo's instance and its plan."""
    inst = load_instance(resolve(DEFAULT_MAP, "map"), resolve(DEFAULT_SCEN, "scen"),
                         DEFAULT_AGENTS)
    return inst, solve(inst.grid, inst.starts, inst.goals, deadline=NeverExpires()).plan


def _demo_in_virtual_time(trace: Path, *, intruder: bool, policy: PolicyName) -> RunSummary:
    """The demo's run (its instance, gateway and simulated fleet with the seed-0 intruder if
    ``intruder``) over real websockets on loopback, in virtual time (a replan's solver
    charged nothing)."""
    inst, plan = _demo_plan()
    config = GatewayConfig(port=0, map=None, policy=policy, threshold_ms=PAPER.threshold_ms,
                           trace=trace, log_level="WARNING")

    async def main() -> RunSummary:
        async with Gateway(config, clock=VirtualClock()) as gw:
            port = await gw.listen()
            fleet = fleet_for(gw, DEFAULT_AGENTS, websocket_connector(
                f"ws://127.0.0.1:{port}/ws"), intruder=intruder)
            try:
                return await run_in_process(gw, Problem(inst, DEFAULT_MAP, plan), fleet)
            finally:
                await fleet.stop()

    return run_virtual(main())


def test_ten_robots_without_intruder_run_safely_in_real_time(tmp_path: Path) -> None:
    # real time, as a user runs it: safe and consistent at any load (how close the SOC comes
    # to the plan's in real time depends on what else the machine runs: the gateway's own
    # time is checked in virtual time below)
    trace = tmp_path / "demo.jsonl"
    out = demo("--no-intruder", "--speed", "5", "--agents", "10", "--trace", str(trace))
    plan_ms = 1000.0 * float(out["plan_soc"])  # type: ignore[arg-type]
    soc = float(out["soc_ms"])  # type: ignore[arg-type]
    assert soc >= plan_ms  # no action is faster than 200 ms of wall time (x5)
    assert out["replans"] == 0 and out["collisions"] == 0
    report = check_trace(read_trace(trace))
    assert report.errors == []
    assert report.collisions == []
    assert report.soc_ms == soc


def test_ten_robots_over_websockets_take_exactly_the_plans_time(tmp_path: Path) -> None:
    # the demo's fleet and gateway (its instance, no intruder) over real websockets on
    # loopback, in virtual time: the gateway and the round trips add no time of their own, so
    # every action starts when the plan says and the SOC is the plan's exactly
    trace = tmp_path / "trace.jsonl"
    out, (_, plan) = _demo_in_virtual_time(trace, intruder=False, policy="none"), _demo_plan()
    assert out.soc_ms == 1000.0 * plan.soc
    assert out.makespan_ms == 1000.0 * plan.makespan
    assert out.replans == 0 and out.collisions == 0
    report = check_trace(read_trace(trace))
    assert report.errors == [] and report.collisions == []
    assert report.soc_ms == out.soc_ms


def test_intruder_and_slack_policy_stay_safe(tmp_path: Path) -> None:
    # the defaults: 10 robots on lab, intruder, slack policy (in real time whether the slack
    # crosses the threshold depends on timing; the safety properties may not)
    trace = tmp_path / "demo.jsonl"
    out = demo("--speed", "10", "--trace", str(trace))
    assert out["collisions"] == 0
    records = read_trace(trace)
    report = check_trace(records)
    assert report.errors == []
    assert report.collisions == []  # robots and the intruder never shared a cell
    assert report.plans == 1 + int(out["replans"])  # type: ignore[call-overload]
    assert report.soc_ms == out["soc_ms"]
    assert any(r["type"] == "intruder" and r["state"] == "on" for r in records)


def test_default_demo_replans_when_the_slack_crosses_the_threshold(tmp_path: Path) -> None:
    # The zero-setup demo (lab-random-4, 10 robots, seed-0 intruder, slack policy), its gateway
    # and fleet over real websockets in virtual time (in real time a loaded machine shifts the
    # crossing): the fleet slack passes 2000 ms at 7100 ms (and 3000 ms at 8100 ms, so the
    # crossing is not marginal) and the replan adopts plan 1.
    # ``fleetgate demo --virtual-time`` (what the GUI tests run: virtual time paced by the
    # wall clock) has exactly these times, whatever the machine's load
    trace = tmp_path / "trace.jsonl"
    out = _demo_in_virtual_time(trace, intruder=True, policy="slack")
    assert out.replans == 1
    assert out.replan_at_ms is not None and 7000 <= out.replan_at_ms <= 8200
    triggers = [r for r in read_trace(trace) if r["type"] == "trigger"]
    assert [t["policy"] for t in triggers] == ["slack"]
    assert float(triggers[0]["fleet_slack_ms"]) > 2000  # type: ignore[arg-type]
    assert check_trace(read_trace(trace)).errors == []
    paced = demo("--virtual-time", "--speed", "20")
    assert (paced["soc_ms"], paced["makespan_ms"], paced["replans"], paced["replan_at_ms"]) \
        == (out.soc_ms, out.makespan_ms, 1, out.replan_at_ms)


def test_virtual_time_is_refused_where_the_world_is_not_in_the_process() -> None:
    for extra in ("--lifelong", "--vda5050"):
        proc = subprocess.run([*FLEETGATE, "demo", "--virtual-time", extra, "--port", "0"],
                              capture_output=True, text=True, timeout=60, check=False)
        assert proc.returncode == 2
        assert proc.stderr == ("fleetgate: --virtual-time runs a one-shot demo over "
                               f"websockets, not {extra}\n")


def test_without_headless_it_keeps_serving_until_ctrl_c() -> None:
    proc = subprocess.Popen([*FLEETGATE, "demo", "--port", "0", "--speed", "20", "--agents", "3",
                             "--no-intruder", "--start", "now"], stdout=subprocess.DEVNULL,
                            stderr=subprocess.PIPE, text=True)
    try:
        assert proc.stderr is not None
        port = None
        for line in proc.stderr:
            m = re.search(r"http://127\.0\.0\.1:(\d+)/", line)
            if m:
                port = int(m[1])
            if "until Ctrl-C" in line:
                break
        assert port is not None
        with urllib.request.urlopen(f"http://127.0.0.1:{port}/healthz", timeout=5) as resp:
            health = json.load(resp)
        assert health["gateway"] == "done"  # the run is over, the gateway still answers
        assert health["robots"] == 3
        proc.send_signal(signal.SIGINT)
        assert proc.wait(timeout=20) == 130  # Ctrl-C, after a clean stop (README)
    finally:
        proc.kill()
        proc.wait()
