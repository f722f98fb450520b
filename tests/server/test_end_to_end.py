"""End-to-end over real websockets on 127.0.0.1: test robots complete plans on the lab map;
reconnects resend what was not acknowledged; a vanished robot's steps stay held."""

from __future__ import annotations

import asyncio
from pathlib import Path

import pytest
from websockets.asyncio.client import ClientConnection, connect

from gateway.server.clock import VirtualClock
from gateway.server.gateway import Gateway
from protocol import Action, Finished, LoadPlan, Start, Started, Welcome
from tests.server.conftest import LAB_PATHS, make_config, virtual_gateway
from tests.server.robots import TestOperator, TestRobot
from tracecheck import check_trace, read_trace

DEPENDENT_PATHS = [
    [(1, 0), (2, 0), (3, 0)],
    [(0, 0), (0, 0), (1, 0)],
]
"""Robot 1 enters (1, 0) at t=2 after robot 0 left it: its action 1 waits for robot 0's
action 0 (a Type 2 edge). 1-robust: robot 1 is never where robot 0 was one step before."""


async def ws(gw: Gateway, token: str) -> ClientConnection:
    """A websocket client authenticated with ``token``."""
    return await connect(f"ws://127.0.0.1:{gw.port}/ws",
                         additional_headers={"Authorization": f"Bearer {token}"}, proxy=None)


async def load(gw: Gateway, paths: list[list[tuple[int, int]]]) -> None:
    """Load a hand-made plan on the lab map."""
    code, detail = await gw.command(LoadPlan(msg_id="l", seq=0, map="lab", paths=paths))
    assert code is None, detail


@pytest.mark.looptime  # virtual time over real websockets
async def test_three_robots_complete_a_plan(tmp_path: Path) -> None:
    async with virtual_gateway(trace=tmp_path / "trace.jsonl") as (gw, _):
        await load(gw, LAB_PATHS)
        op = TestOperator(await ws(gw, "demo-operator"), "op")
        snap = await op.snapshot()
        assert snap.status == "loaded" and snap.map_name == "lab"
        lab = (Path(__file__).parents[2] / "gateway/planning/maps/lab.map").read_text().split()
        assert snap.rows == lab[lab.index("map") + 1:]
        assert [r.cell for r in snap.robots] == [p[0] for p in LAB_PATHS]
        assert [r.connected for r in snap.robots] == [False] * 3
        robots = [TestRobot(await ws(gw, f"demo-robot-{i}"), i, move_s=0.02) for i in range(3)]
        welcomes = [await r.hello() for r in robots]
        assert [w.start.cell for w in welcomes if w.start] == [p[0] for p in LAB_PATHS]
        tasks = [asyncio.create_task(r.run()) for r in robots]
        await op.send(Start)
        soc, makespan = await asyncio.wait_for(gw.wait_done(), 20)
        summary = await op.event("summary")
        assert (summary.soc_ms, summary.makespan_ms) == (soc, makespan)
        for t in tasks:
            t.cancel()
        # every action ran exactly once, in ADG order, with no shared cells (independent checker)
        report = check_trace(read_trace(tmp_path / "trace.jsonl"))
        assert report.ok, report.errors
        assert report.actions_run == sum(len(p) - 1 for p in LAB_PATHS) == 10
        assert [len(r.finished) for r in robots] == [5, 3, 2]
        # 3 actions are dispatched at start, the other 7 each unlocked by one finish
        assert len(gw.latencies_ms) == 7
        assert all(lat >= 0 for lat in gw.latencies_ms)
        assert all(h.acked for rec in gw.engine.robots.values() for h in rec.held.values())
        assert gw.status == "done"


@pytest.mark.looptime  # virtual time over real websockets
async def test_reconnect_resends_the_unacknowledged_action() -> None:
    async with virtual_gateway() as (gw, _):
        await load(gw, LAB_PATHS[:1])
        robot = TestRobot(await ws(gw, "demo-robot-0"), 0, ack=False)
        await robot.hello()
        await gw.command(Start(msg_id="s", seq=1))
        first = await robot.expect(Action)
        await robot.link.close()
        await asyncio.wait_for(_until(lambda: gw.engine.robot(0).link is None), 5)
        held = gw.engine.robot(0).held
        assert list(held) == [first.action_id] and not held[first.action_id].acked
        again = TestRobot(await ws(gw, "demo-robot-0"), 0)
        welcome: Welcome = await again.hello()
        assert [a.action_id for a in welcome.resend] == [first.action_id]
        assert welcome.resend[0].dst == first.dst
        task = asyncio.create_task(again.run())
        await asyncio.wait_for(gw.wait_done(), 10)
        task.cancel()
        assert again.finished == [f"0.0.{i}" for i in range(5)]


@pytest.mark.looptime  # virtual time over real websockets
async def test_finish_lost_with_the_link_is_recovered_from_hello() -> None:
    async with virtual_gateway() as (gw, _):
        await load(gw, LAB_PATHS[:1])
        robot = TestRobot(await ws(gw, "demo-robot-0"), 0)
        await robot.hello()
        await gw.command(Start(msg_id="s", seq=1))
        await robot.expect(Action)
        await robot.send(Started, action_id="0.0.0")
        await robot.link.close()  # the finished report never makes it
        await asyncio.wait_for(_until(lambda: gw.engine.robot(0).link is None), 5)
        again = TestRobot(await ws(gw, "demo-robot-0"), 0)
        welcome = await again.hello(finished=["0.0.0"])
        assert [a.action_id for a in welcome.resend] == ["0.0.1"]
        assert gw.engine.robot(0).applied == {"0.0.0": "finished"}
        ref = await again.send(Finished, action_id="0.0.0")
        assert (await again.error_for(ref)).code == "duplicate"


@pytest.mark.looptime  # virtual time over real websockets
async def test_vanished_robot_keeps_its_steps_held() -> None:
    async with virtual_gateway() as (gw, _):
        await load(gw, DEPENDENT_PATHS)
        r0 = TestRobot(await ws(gw, "demo-robot-0"), 0)
        r1 = TestRobot(await ws(gw, "demo-robot-1"), 1, move_s=0.01)
        await r0.hello()
        await r1.hello()
        t1 = asyncio.create_task(r1.run())
        await gw.command(Start(msg_id="s", seq=1))
        await r0.expect(Action)
        await r0.link.close()  # robot 0 vanishes before moving
        await asyncio.wait_for(_until(lambda: r1.finished == ["0.1.0"]), 5)
        await asyncio.sleep(0.3)  # three monitor periods: nothing may move robot 1 on
        assert r1.finished == ["0.1.0"]
        assert "0.1.1" not in gw.engine.robot(1).held
        back = TestRobot(await ws(gw, "demo-robot-0"), 0, move_s=0.01)
        welcome = await back.hello()
        assert [a.action_id for a in welcome.resend] == ["0.0.0"]
        t0 = asyncio.create_task(back.run())
        await asyncio.wait_for(gw.wait_done(), 10)
        assert r1.finished == ["0.1.0", "0.1.1"]
        for t in (t0, t1):
            t.cancel()


async def _until(predicate: object) -> None:
    while not predicate():  # type: ignore[operator]
        await asyncio.sleep(0.01)


@pytest.mark.looptime  # virtual time over real websockets
async def test_silent_link_is_dropped_by_ping_timeout() -> None:
    async with Gateway(make_config(ping_interval_s=0.5, ping_timeout_s=0.5),
                       clock=VirtualClock()) as gw:
        await gw.listen()
        await _silent_robot_is_dropped(gw)


async def _silent_robot_is_dropped(gw: Gateway) -> None:
    await load(gw, DEPENDENT_PATHS)
    r0 = TestRobot(await ws(gw, "demo-robot-0"), 0)
    await r0.hello()
    await gw.command(Start(msg_id="s", seq=1))
    await r0.expect(Action)
    r0.link.transport.pause_reading()  # type: ignore[attr-defined]  # pongs stop coming back
    # a ping every 0.5 s, 0.5 s to answer: the gateway gives up and holds the steps
    await asyncio.wait_for(_until(lambda: gw.engine.robot(0).link is None), 10)
    assert list(gw.engine.robot(0).held) == ["0.0.0"]
    assert gw.status == "running"


@pytest.mark.looptime  # virtual time over real websockets
async def test_autostart_when_every_robot_said_hello() -> None:
    async with Gateway(make_config(autostart=True), clock=VirtualClock()) as gw:
        await gw.listen()
        await load(gw, LAB_PATHS)
        robots = [TestRobot(await ws(gw, f"demo-robot-{i}"), i, move_s=0.1) for i in range(3)]
        for r in robots[:2]:
            await r.hello()
        assert gw.status == "loaded"  # robot 2 is still missing
        await robots[2].hello()
        tasks = [asyncio.create_task(r.run()) for r in robots]
        soc, _ = await asyncio.wait_for(gw.wait_done(), 10)
        # started at the last hello; 100 ms an action, none waits for another robot:
        # 500 + 300 + 200 ms
        assert soc == 1000.0 and [len(r.finished) for r in robots] == [5, 3, 2]
        for t in tasks:
            t.cancel()
