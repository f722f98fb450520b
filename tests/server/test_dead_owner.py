"""The owner task dies (issue 26, defect 1): ``fleetgate serve`` whose trace file cannot be
written (``/dev/full``: every write fails with ENOSPC at the lowest layer) runs a one-shot
plan; the first trace flush, right after a journal commit in the owner task, raises out of it.
The process must then end by itself with one line and exit 70 (no listening zombie, no
traceback), and the journal it leaves is consistent: a gateway restarted on it with a
writable trace resumes the run, the robots complete it, and that trace is one valid run with
every action finished once."""

from __future__ import annotations

import asyncio
import json
import random
import time
from collections import Counter
from pathlib import Path
from typing import Any

import pytest

from bench.crash import GatewayProcess, _operator, free_port
from gateway.planning.movingai import write_map
from gateway.planning.random_plans import open_grid, random_plan
from gateway.runtime.exits import EXIT_SOFTWARE
from gateway.server.clock import LoopClock
from protocol import LoadPlan, Start
from sim_clients.connect import websocket_connector
from sim_clients.fleet import SimFleet
from tracecheck import check_trace, read_trace

FULL = Path("/dev/full")


@pytest.mark.skipif(not FULL.exists(), reason="no /dev/full on this system")
def test_a_dead_owner_task_exits_70_with_one_line_and_a_consistent_journal(
        tmp_path: Path) -> None:
    speed, robots = 5.0, 4
    grid = open_grid(6, 6)
    plan = random_plan(grid, robots, 12, random.Random(26))
    map_file = tmp_path / "open.map"
    write_map(grid, map_file)
    gw = GatewayProcess(tmp_path, free_port(), speed, "none")
    trace = gw.trace
    config = json.loads(gw.config.read_text())
    gw.config.write_text(json.dumps({**config, "trace": str(FULL)}))
    executed: Counter[tuple[int, int, int]] = Counter()
    out: dict[str, Any] = {}

    def on_event(kind: str, p: int, r: int, i: int) -> None:
        if kind == "execute":
            executed[(p, r, i)] += 1

    fleet = SimFleet(websocket_connector(f"ws://127.0.0.1:{gw.port}/ws"), range(robots),
                     clock=LoopClock(speed), send_state=False, reconnect_delay_s=0.05,
                     seed=26, must_only=True)
    fleet.on_event = on_event

    async def main() -> None:
        try:
            await run()
        finally:
            await fleet.stop()

    async def run() -> None:
        await asyncio.to_thread(gw.start)
        await fleet.start()
        await fleet.wait_connected(timeout=60.0)
        # the load's trace record is flushed after its commit: the owner dies there
        with_error = asyncio.ensure_future(_operator(
            gw.port, LoadPlan(msg_id="load", seq=0, map=str(map_file),
                              paths=[list(p) for p in plan.paths]), Start(msg_id="go", seq=0)))
        assert gw.proc is not None
        out["code"] = await asyncio.to_thread(gw.proc.wait, 120)  # a bound for a hang only
        gw.proc = None
        out["log"] = gw.log_path.read_text()
        with_error.cancel()
        gw.config.write_text(json.dumps({**config, "trace": str(trace)}))
        await asyncio.to_thread(gw.start)  # the same journal, a writable trace
        out["resumed_as"] = (await asyncio.to_thread(gw.health)).get("gateway")
        if out["resumed_as"] == "loaded":  # the start's record did not make it: start again
            await _operator(gw.port, Start(msg_id="go", seq=0))
        deadline = time.monotonic() + 240.0  # a bound for a hang only (the run: 3 s)
        while time.monotonic() < deadline:
            if (await asyncio.to_thread(gw.health)).get("gateway") == "done":
                break
            await asyncio.sleep(0.1)
        out["done"] = (await asyncio.to_thread(gw.health)).get("gateway") == "done"

    try:
        asyncio.run(main())
    finally:
        gw.stop()
    assert out["code"] == EXIT_SOFTWARE, out["log"][-2000:]
    lines = [ln for ln in out["log"].splitlines() if ln.strip()]
    assert "Traceback" not in out["log"], out["log"][-2000:]
    dead = [ln for ln in lines if "owner task ended" in ln]
    assert len(dead) == 1 and "No space left on device" in dead[0], lines
    assert out["done"], gw.log_path.read_text()[-2000:]
    assert [a for a, n in executed.items() if n > 1] == []
    records = read_trace(trace)
    report = check_trace(records)
    assert report.errors == [] and report.collisions == []
    finishes = [(r["plan"], r["robot"], r["action"]) for r in records if r["type"] == "finish"]
    assert len(finishes) == len(set(finishes)) == sum(len(p) - 1 for p in plan.paths)
