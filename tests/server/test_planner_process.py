"""The lifelong planner in its own process, over real websockets on 127.0.0.1: a shift fed only
by a simulated WMS through the task API (``task_list = false``), its planner process killed
with SIGKILL mid-shift: one error line, the next period plans in a new process, the shift goes
on collision-free (independent checker), and the process ends with the gateway."""

from __future__ import annotations

import asyncio
import logging
import os
import signal
from pathlib import Path
from typing import Any

import pytest

from gateway.runtime.solver_time import SolverTime
from gateway.server.clock import VirtualClock, run_virtual
from gateway.server.config import GatewayConfig, LifelongSettings
from gateway.server.gateway import Gateway
from gateway.server.runs.planner_process import PlannerDied, PlannerProcess
from sim_clients.connect import websocket_connector
from sim_clients.fleet import SimFleet
from sim_clients.shift import ShiftStats, run_shift, start_shift, stop_shift
from sim_clients.wms import Wms
from tracecheck import check_trace, read_trace

ROBOTS = 8


def _cmdline(pid: int) -> str:
    return Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode()


def test_a_killed_planner_process_costs_one_error_line_and_the_shift_goes_on(
        tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    trace = tmp_path / "trace.jsonl"
    out: dict[str, Any] = {}

    async def main() -> None:
        config = GatewayConfig(
            port=0, map=None, autostart=True, speed=10.0, trace=trace, log_level="WARNING",
            lifelong=LifelongSettings(robots=ROBOTS, warehouse=(2, 3), task_list=False))
        async with Gateway(config) as gw:
            run = gw.engine.lifelong
            assert run is not None
            first = out["first"] = run.planner.pid
            assert first is not None and first != os.getpid()
            assert "gateway.server.runs.planner_process" in _cmdline(first)
            port = await gw.listen()
            grid = run.shift.grid
            free = [grid.cell(c) for c in range(grid.size) if grid.free.ravel()[c]]
            tasks = [(free[(7 * i) % len(free)], free[(13 * i + 5) % len(free)])
                     for i in range(60)]
            wms = Wms(port, "demo-operator", tasks, keep=run.shift.reveal, lead=4, batch=5)
            await wms.fill()
            assert wms.stats.submitted == run.shift.reveal + 4 and wms.stats.posts >= 2
            feeding = asyncio.get_running_loop().create_task(wms.run())
            fleet = SimFleet(websocket_connector(f"ws://127.0.0.1:{port}/ws"), range(ROBOTS),
                             clock=gw.clock, send_state=False, duration_jitter=0.2)
            await start_shift(gw, fleet)
            ex = run.executor
            while ex.segments < 5:
                await asyncio.sleep(0.02)
            os.kill(first, signal.SIGKILL)
            before = ex.segments
            while run.planner.starts < 2 or ex.segments < before + 10:
                await asyncio.sleep(0.02)
            out["second"] = run.planner.pid
            out["finished_mid"] = ex.finished_tasks
            mid = gw.engine.now_ms()  # then until a task more is finished (a loaded machine
            # slows the shift down: a bound for a stalled shift, 4 real minutes, not a duration)
            while ex.finished_tasks <= out["finished_mid"] and gw.engine.now_ms() < mid + 2400e3:
                await asyncio.sleep(0.05)
            out["stats"] = await stop_shift(gw, fleet)
            out["errors"] = list(fleet.stats.errors)
            await fleet.stop()
            out["wms"] = wms.stats
        out["gone"] = [p for p in (first, out["second"]) if Path(f"/proc/{p}").exists()]
        await asyncio.wait_for(feeding, 60.0)  # the WMS stops when the gateway is gone

    with caplog.at_level(logging.ERROR, logger="fleetgate.lifelong"):
        asyncio.run(main())
    died = [r for r in caplog.records if r.getMessage() == "lifelong planner process died"]
    assert len(died) == 1
    error = died[0].__dict__["error"]
    assert "killed by signal 9" in error and "\n" not in error
    assert out["second"] not in (None, out["first"])
    assert out["gone"] == []  # both planner processes ended
    stats = out["stats"]
    assert out["errors"] == [] and stats.lost == 0 and stats.duplicated == 0
    assert stats.collisions == 0 and stats.finished_tasks > out["finished_mid"] >= 0
    report = check_trace(read_trace(trace))
    assert report.errors == [] and report.collisions == []
    wms = out["wms"]  # it topped up as tasks ended, never leaving the pool short
    assert wms.ended > 0 and wms.submitted >= wms.ended + 8 and wms.posts > 2
    assert wms.min_lead is not None and wms.min_lead >= 0


def test_a_planner_process_answers_reports_errors_and_restarts() -> None:
    from gateway.execution.lifelong.executor import PlanRequest
    from gateway.planning.lorr import warehouse_problem

    prob = warehouse_problem(4, 0, (2, 3), p_delay=0.0)
    planner = PlannerProcess(prob.grid, 4, turning=False)
    try:
        planner.start()
        req = PlanRequest(0, prob.starts, tuple((t[0],) for t in prob.tasks[:4]), (0,) * 4,
                          (), 3)
        segment, cpu_ms = planner.call(req)
        assert len(segment.states) == 4 and segment.states[0] == list(prob.starts)
        assert cpu_ms >= 0.0
        clash = PlanRequest(1, (prob.starts[0],) * 4, req.goals, req.hold, (), 3)
        with pytest.raises(Exception, match="two robots stand on the same cell"):
            planner.call(clash)
        pid = planner.pid
        assert pid is not None
        os.kill(pid, signal.SIGKILL)
        with pytest.raises(PlannerDied, match=rf"pid {pid}\) died \(killed by signal 9\)"):
            planner.call(req)
        assert planner.call(req)[0].call == 0 and planner.starts == 2
    finally:
        planner.close()
    assert planner.pid is None
    with pytest.raises(PlannerDied, match="closed"):
        planner.call(req)


@pytest.mark.parametrize("solver_time", [250.0, "measured"])
def test_under_virtual_time_the_planner_process_is_charged_as_told(
        solver_time: SolverTime) -> None:
    """In-memory robots, virtual time: each call's segment arrives after the charged time
    (a fixed 250 ms, or the CPU time the worker measured), and the shift runs as usual."""

    async def main() -> tuple[list[float], int, ShiftStats]:
        config = GatewayConfig(port=0, map=None, autostart=True, log_level="WARNING",
                               lifelong=LifelongSettings(robots=6, warehouse=(2, 3)))
        async with Gateway(config, clock=VirtualClock(solver_time=solver_time)) as gw:
            run = gw.engine.lifelong
            assert run is not None and run.planner.pid is not None
            fleet = SimFleet(gw.connect, range(6), clock=gw.clock, send_state=False)
            stats = await run_shift(gw, fleet, 30_000.0)
            return list(run.planner_ms), run.executor.segments, stats

    charged, segments, stats = run_virtual(main())
    assert segments >= 20 and len(charged) >= segments
    if solver_time == "measured":
        assert charged[0] > 0.0 and all(0.0 <= ms < 5000.0 for ms in charged)
    else:
        assert set(charged) == {250.0}
    assert stats.finished_tasks >= 3 and stats.lost == stats.duplicated == 0
    assert stats.collisions == 0
