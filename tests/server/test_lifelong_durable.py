"""A lifelong shift survives SIGKILL: ``fleetgate serve`` (its own process) runs a warehouse shift
of simulated robots over real websockets, is killed with SIGKILL twice mid-shift (robots
running actions, a planner call possibly outstanding) and restarted with the same command
line; the robots reconnect by themselves and the SAME shift goes on (its journal compacted
into a snapshot every five segments, so each restart resumes from one). The independent checker
(tracecheck) reads the one trace file the three processes appended to
(``bench.crash.lifelong_shift``, the crash benchmark's ``--lifelong`` shift, counts what went
wrong)."""

from __future__ import annotations

import asyncio
import random
import threading
from pathlib import Path
from typing import Any

import pytest

from bench.crash import (
    GatewayProcess,
    Progress,
    free_port,
    lifelong_config,
    lifelong_shift,
    shift_defects,
)
from gateway.execution.lifelong.executor import PlanRequest, Segment
from gateway.planning.lorr import warehouse_problem
from gateway.runtime.journal import Journal
from gateway.server.clock import VirtualClock, run_virtual
from gateway.server.config import GatewayConfig, LifelongSettings
from gateway.server.gateway import Gateway
from gateway.server.items import OwnerCall
from gateway.server.runs.planner_process import PlannerProcess
from protocol import SetThreshold
from sim_clients.connect import websocket_connector
from sim_clients.fleet import SimFleet
from sim_clients.shift import start_shift, stop_shift
from tracecheck import check_trace, read_trace

ROBOTS = 6


def test_a_killed_lifelong_gateway_continues_the_same_shift(tmp_path: Path) -> None:
    gw = GatewayProcess(tmp_path, free_port(), speed=10.0, policy="none")
    lifelong_config(gw, ROBOTS, (2, 3), snapshot_segments=5)  # compacted every 0.5 s
    rng = random.Random(7)
    grid = warehouse_problem(ROBOTS, 0, (2, 3), p_delay=0.0).grid
    # killed on progress, not after a wall-clock delay (a loaded machine gets there later):
    # each kill once a task finished and 40-80 more actions (~7-13 segments: compacted) were
    # completed since the last restart, at a random point of the robots' actions
    kills = [Progress(actions=rng.randint(40, 80), tasks=1) for _ in range(2)]
    out = asyncio.run(lifelong_shift(gw, ROBOTS, 10.0, kills, Progress(actions=40, tasks=1),
                                     rng, grid, progress_timeout_s=90.0))
    assert out["stalled"] == 0  # after the start and each restart the shift got that far
    assert out["resumed"] == 2  # both restarts went on with the shift
    assert out["from_snapshot"] == 2  # from a compacted journal: a snapshot, then records
    assert out["run_ids"] == 1  # the robots saw one run: action ids went on
    # no collision, no other trace error, one shift start, plan time never went back,
    # no segment or action number repeated or skipped, nothing dispatched or executed twice,
    # every completion made before a kill in the trace, the batch's idempotency key kept,
    # task event ids without a gap, no task finished twice or moved once started
    for key in ("collisions", "trace_errors", "renumbered", "dispatched_twice", "duplicated",
                "lost", "retry_created", "event_gaps", "finished_twice", "robot_changed",
                "robot_errors"):
        assert out[key] == 0, (key, out)
    # the robots completed 120 or more (3 x 40 at least); the trace has them (but the last
    # few, reported while the fleet stopped)
    assert out["actions_run"] > 100
    assert out["tasks_finished"] > out["finished_at_last_kill"] > 0  # the shift went on



def test_a_planner_call_outstanding_at_the_crash_is_planned_again(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The gateway goes down while a planner call runs (its segment never journaled); the
    restarted one replays the shift up to that call, plans it again and the shift goes on."""
    slow, held, release = threading.Event(), threading.Event(), threading.Event()
    plan = PlannerProcess.call

    def planner(self: PlannerProcess, req: PlanRequest) -> tuple[Segment, float]:
        if slow.is_set():  # held in the planner's thread until the gateway is down
            out["held"] = req.call
            held.set()
            release.wait(300)
        return plan(self, req)

    monkeypatch.setattr(PlannerProcess, "call", planner)
    journal = tmp_path / "journal.sqlite"
    config = GatewayConfig(port=free_port(), map=None, autostart=True, speed=10.0,
                           trace=tmp_path / "trace.jsonl", journal=journal,
                           log_level="WARNING",
                           lifelong=LifelongSettings(robots=ROBOTS, warehouse=(2, 3)))
    out: dict[str, Any] = {}

    async def started() -> tuple[Gateway, Any]:
        gw = Gateway(config)
        await gw.start()
        ex = gw.engine.lifelong.executor  # type: ignore[union-attr]
        out.setdefault("at_start", []).append(
            (ex.outstanding.call if ex.outstanding is not None else None, ex.segments))
        await gw.listen()
        return gw, ex

    async def main() -> None:
        gw, ex = await started()
        fleet = SimFleet(websocket_connector(f"ws://127.0.0.1:{config.port}/ws"),
                         range(ROBOTS), clock=gw.clock, send_state=False,
                         reconnect_delay_s=0.05)
        try:
            await start_shift(gw, fleet)
            run = gw.engine.run_id
            while ex.segments < 3:
                await asyncio.sleep(0.02)
            slow.set()
            while not held.is_set():  # the next call is running in the planner's thread
                await asyncio.sleep(0.02)
            assert ex.outstanding is not None and ex.outstanding.call == out["held"]
            out["call"], out["segments"] = ex.outstanding.call, ex.segments
            await gw.stop()  # down in the middle of the call: its answer is never adopted
            slow.clear()
            release.set()
            out["kinds"] = [r.kind for r in Journal(journal).records()]
            gw, ex = await started()  # the robots reconnect by themselves
            out["resumed"] = (gw.resumed, gw.engine.run_id == run)
            while ex.segments < out["segments"] + 5:
                await asyncio.sleep(0.02)
            out["stats"] = await stop_shift(gw, fleet)
        finally:
            release.set()
            await fleet.stop()
            await gw.stop()

    async def bounded() -> None:
        async with asyncio.timeout(300):  # a call never planned again stalls the shift
            await main()

    asyncio.run(bounded())
    # the call's answer was not journaled; the restart replayed the shift up to the call,
    # which was outstanding again (and then answered: the shift went on)
    assert out["kinds"].count("segment") == out["segments"]
    assert out["resumed"] == (True, True)
    assert out["at_start"] == [(None, 0), (out["call"], out["segments"])]
    stats = out["stats"]
    assert stats.lost == 0 and stats.duplicated == 0 and stats.collisions == 0
    records = read_trace(tmp_path / "trace.jsonl")
    assert check_trace(records).ok
    assert shift_defects(records)["renumbered"] == 0


@pytest.mark.parametrize("every", [0, 3])
def test_the_operators_slack_threshold_survives_a_restart(tmp_path: Path, every: int) -> None:
    """The operator sets the shift's slack threshold; a restarted gateway shows it to
    operators (and its executor uses it) again, from the journaled threshold record, or from
    the snapshot that compacted it (``every`` 3: the record itself is gone)."""
    config = GatewayConfig(port=0, map=None, autostart=False, speed=10.0,
                           journal=tmp_path / "journal.sqlite", log_level="WARNING",
                           lifelong=LifelongSettings(robots=ROBOTS, warehouse=(2, 3),
                                                     snapshot_segments=every))
    out: dict[str, Any] = {}

    async def main() -> None:  # in virtual time: nothing here is about the real clock
        async with Gateway(config, clock=VirtualClock(solver_time=120.0)) as gw:
            run = gw.engine.lifelong
            assert run is not None and gw.engine.journal is not None
            assert gw.engine.threshold_ms != 1234.0
            gw.engine.queue.put_nowait(OwnerCall(run.start))
            assert (await gw.command(SetThreshold(msg_id="t", seq=0,
                                                  threshold_ms=1234.0)))[0] is None
            while run.executor.segments < 7:
                await asyncio.sleep(0.02)
            out["kinds"] = [r.kind for r in gw.engine.journal.records()]
        async with Gateway(config, clock=VirtualClock(solver_time=120.0)) as again:
            assert again.resumed and again.engine.lifelong is not None
            out["shown"] = again.engine.read_model().threshold_ms
            out["used"] = again.engine.lifelong.executor.threshold_ms

    run_virtual(main())
    assert out["shown"] == out["used"] == 1234.0
    assert ("threshold" in out["kinds"]) == (every == 0)
    assert (out["kinds"][0] in ("shift_history", "shift_snapshot")) == (every > 0)
