"""The operator API over real websockets: snapshot on connect, event stream, commands
(load_instance, start, pause/resume, replan_now, settings, intruder relay) and their errors."""

from __future__ import annotations

import asyncio
from pathlib import Path
from typing import Any

import pytest

from gateway.server.clock import VirtualClock
from gateway.server.gateway import Gateway
from protocol import (
    Ack,
    AnyMessage,
    Error,
    ErrorCode,
    Event,
    GenerateParams,
    GetSnapshot,
    IntruderReport,
    LoadInstance,
    LoadPlan,
    Ok,
    Pause,
    PlaceIntruder,
    ReplanNow,
    Resume,
    SetPolicy,
    SetSpeed,
    SetThreshold,
    Snapshot,
    Start,
)
from tests.server.conftest import Connect, connector, make_config, virtual_gateway
from tests.server.robots import Peer, TestOperator, TestRobot
from tracecheck import check_trace, read_trace


async def operator(ws_connect: Connect) -> TestOperator:
    """A connected operator that has read its initial snapshot."""
    op = TestOperator(await ws_connect("demo-operator"), "op")
    await op.snapshot()
    return op


async def ok(op: Peer, kind: type[AnyMessage], **fields: Any) -> Ok:
    """Send a command and wait for its ``ok`` (fails on an error)."""
    ref = await op.send(kind, **fields)
    async with asyncio.timeout(30):
        while True:
            msg = await op.recv()
            if isinstance(msg, Ok | Error) and msg.ref == ref:
                assert isinstance(msg, Ok), msg
                return msg


async def fleet(ws_connect: Connect, n: int, move_s: float) -> tuple[list[TestRobot],
                                                                     list[asyncio.Task[None]]]:
    """``n`` robots that said hello and execute what they get."""
    robots = [TestRobot(await ws_connect(f"demo-robot-{i}"), i, move_s=move_s)
              for i in range(n)]
    for r in robots:
        await r.hello()
    return robots, [asyncio.create_task(r.run()) for r in robots]


async def barrier(robots: list[TestRobot], op: TestOperator) -> None:
    """Wait until the gateway handled everything the robots sent so far and the events it
    caused reached ``op``: each robot gets the reply to a probe (an ack of an unknown action,
    answered in order on its connection), then ``op`` a snapshot (after those events)."""
    for r in robots:
        ref = await r.send(Ack, action_id=f"999.{r.robot_id}.0")
        async with asyncio.timeout(10):
            while not any(isinstance(m, Error) and m.ref == ref for m in r.inbox):
                await asyncio.sleep(0.01)
    await _snapshot(op)


@pytest.mark.looptime  # virtual time over real websockets
async def test_load_instance_start_and_event_stream() -> None:
    async with virtual_gateway() as (gateway, ws_connect):
        op = await operator(ws_connect)
        done = await ok(op, LoadInstance, map="lab", scen="lab-random-1", agents=3)
        assert "3 robots" in done.detail
        snap: Snapshot = await op.snapshot()  # pushed to every operator on load
        assert snap.status == "loaded" and len(snap.paths) == 3 and len(snap.robots) == 3
        _, tasks = await fleet(ws_connect, 3, 0.01)
        await ok(op, Start)
        await asyncio.wait_for(gateway.wait_done(), 20)
        await op.event("summary")
        events = [m for m in op.inbox if isinstance(m, Event)]
        kinds = [e.event for e in events]
        total = sum(len(p) - 1 for p in snap.paths)
        assert kinds.count("plan") == 1
        assert kinds.count("dispatch") == kinds.count("start") == kinds.count("finish") == total
        # from the plan on (time 0 = start), the stream is in time order
        run = events[kinds.index("plan"):]
        assert [e.t_ms for e in run] == sorted(e.t_ms for e in run)
        for t in tasks:
            t.cancel()
        final = await _snapshot(op)
        assert final.status == "done" and final.actions.finished == total
        assert final.soc_ms == gateway.engine.summary[0]  # type: ignore[index]


@pytest.mark.looptime  # virtual time over real websockets
async def test_load_instance_can_generate_starts_and_goals() -> None:
    async with virtual_gateway() as (_, ws_connect):
        op = await operator(ws_connect)
        await ok(op, LoadInstance, map="lab", generate=GenerateParams(seed=5), agents=6)
        snap = await op.snapshot()
        starts = [tuple(p[0]) for p in snap.paths]
        goals = [tuple(p[-1]) for p in snap.paths]
        assert len(set(starts)) == len(set(goals)) == 6
        again = await ok(op, LoadInstance, map="lab", generate=GenerateParams(seed=5), agents=6)
        assert "6 robots" in again.detail
        # same seed, same starts
        assert [tuple(p[0]) for p in (await op.snapshot()).paths] == starts


@pytest.mark.looptime  # virtual time over real websockets
async def test_pause_stops_new_moves_until_resume() -> None:
    async with virtual_gateway() as (gateway, ws_connect):
        op = await operator(ws_connect)
        await ok(op, LoadInstance, map="lab", scen="lab-random-2", agents=3)
        robots, tasks = await fleet(ws_connect, 3, 0.05)
        await ok(op, Start)
        await op.event("finish")
        await ok(op, Pause)
        assert gateway.status == "paused"
        async with asyncio.timeout(5):
            while not all(any(isinstance(m, Pause) for m in r.inbox) for r in robots):
                await asyncio.sleep(0.01)
        # moves already under way may finish; after that nothing starts while paused
        await barrier(robots, op)
        starts = sum(1 for m in op.inbox if isinstance(m, Event) and m.event == "start")
        await asyncio.sleep(0.3)
        await barrier(robots, op)
        assert sum(1 for m in op.inbox if isinstance(m, Event) and m.event == "start") == starts
        assert (await _snapshot(op)).status == "paused"
        await ok(op, Resume)
        await asyncio.wait_for(gateway.wait_done(), 20)
        for t in tasks:
            t.cancel()


@pytest.mark.looptime  # virtual time over real websockets
async def test_replan_now_adopts_a_new_plan(tmp_path: Path) -> None:
    async with Gateway(make_config(trace=tmp_path / "t.jsonl", policy="none"),
                       clock=VirtualClock()) as gw:
        await gw.listen()
        connect = connector(gw)
        op = await operator(connect)
        await ok(op, LoadInstance, map="lab", scen="lab-random-3", agents=4)
        _, tasks = await fleet(connect, 4, 0.05)
        await ok(op, Start)
        await op.event("finish")
        await ok(op, ReplanNow)
        trigger = await op.event("trigger")
        assert trigger.policy == "operator"
        plan = await op.event("plan")
        assert plan.plan == 1 and plan.paths is not None
        await asyncio.wait_for(gw.wait_done(), 20)
        for t in tasks:
            t.cancel()
        report = check_trace(read_trace(tmp_path / "t.jsonl"))
        assert report.ok, report.errors
        assert report.plans == 2
        # a second replan exceeds the budget of one
        ref = await op.send(ReplanNow)
        assert (await op.error_for(ref)).code is ErrorCode.BAD_STATE


@pytest.mark.looptime  # virtual time over real websockets
async def test_settings_show_in_the_snapshot_and_reach_the_world() -> None:
    async with virtual_gateway() as (gateway, ws_connect):
        op = await operator(ws_connect)
        world = Peer(await ws_connect("demo-world"), "w")
        assert (await world.expect(SetSpeed)).speed == 1.0
        await ok(op, SetPolicy, policy="random", seed=3)
        await ok(op, SetThreshold, threshold_ms=1234.0)
        await ok(op, SetSpeed, speed=4.0)
        assert (await world.expect(SetSpeed)).speed == 4.0
        snap = await _snapshot(op)
        assert (snap.policy, snap.threshold_ms, snap.speed) == ("random", 1234.0, 4.0)
        assert gateway.clock.speed == 4.0


@pytest.mark.looptime  # virtual time over real websockets
async def test_intruder_is_forwarded_to_the_world_and_reports_relayed() -> None:
    async with virtual_gateway() as (gateway, ws_connect):
        op = await operator(ws_connect)
        ref = await op.send(PlaceIntruder, cell=(4, 4), duration_ms=3000.0)
        assert (await op.error_for(ref)).code is ErrorCode.BAD_STATE  # no world yet
        world = Peer(await ws_connect("demo-world"), "w")
        await world.expect(SetSpeed)
        await ok(op, PlaceIntruder, cell=(4, 4), duration_ms=3000.0)
        placed = await world.expect(PlaceIntruder)
        assert (placed.cell, placed.duration_ms) == ((4, 4), 3000.0)
        await world.send(IntruderReport, cell=(4, 4), state="on")
        on = await op.event("intruder")
        assert (on.cell, on.state) == ((4, 4), "on")
        assert (await _snapshot(op)).intruders == [(4, 4)]
        await world.send(IntruderReport, cell=(4, 4), state="off")
        assert (await op.event("intruder")).state == "off"
        assert (await _snapshot(op)).intruders == []
        assert gateway.engine.executor is None  # the executor never saw it


@pytest.mark.looptime  # virtual time over real websockets
async def test_command_errors() -> None:
    async with virtual_gateway() as (gateway, ws_connect):
        op = await operator(ws_connect)
        cases: list[tuple[type[AnyMessage], dict[str, Any], ErrorCode]] = [
            (Start, {}, ErrorCode.BAD_STATE),
            (Resume, {}, ErrorCode.BAD_STATE),
            (ReplanNow, {}, ErrorCode.BAD_STATE),
            (LoadInstance, {"map": "no-such-map", "agents": 2}, ErrorCode.BAD_REQUEST),
            (LoadInstance, {"map": "lab", "scen": "lab-random-1", "agents": 500},
             ErrorCode.BAD_REQUEST),
            (LoadPlan, {"map": "lab", "paths": [[(0, 0), (1, 0)], [(1, 0), (0, 0)]]},
             ErrorCode.BAD_REQUEST),  # a swap: not 1-robust
            (PlaceIntruder, {"cell": (2, 2), "duration_ms": 1.0}, ErrorCode.BAD_STATE),
        ]
        for kind, fields, code in cases:
            ref = await op.send(kind, **fields)
            err = await op.error_for(ref)
            assert err.code is code, (kind, err.detail)
        assert gateway.status == "empty"


async def _snapshot(op: TestOperator) -> Snapshot:
    await op.send(GetSnapshot)
    return await op.snapshot()
