"""Lookahead dispatch through the real gateway (websockets on 127.0.0.1, the default
``dispatch_lookahead=1``): robots hold up to two actions, reconnects resend both in index
order, a finish lost with the link is recovered, and the trace passes the independent checker."""

from __future__ import annotations

import asyncio
from pathlib import Path

import pytest

from gateway.server.clock import VirtualClock
from gateway.server.gateway import Gateway
from protocol import Action, Finished, Start, Started, Welcome
from tests.server.conftest import LAB_PATHS, make_config
from tests.server.robots import TestOperator, TestRobot
from tests.server.test_end_to_end import DEPENDENT_PATHS, _until, load, ws
from tracecheck import check_trace, read_trace

pytestmark = pytest.mark.looptime  # virtual time over real websockets


async def test_robots_get_their_next_action_before_they_finish(tmp_path: Path) -> None:
    async with Gateway(make_config(dispatch_lookahead=1, trace=tmp_path / "t.jsonl"),
                       clock=VirtualClock()) as gw:
        await gw.listen()
        await load(gw, LAB_PATHS)
        op = TestOperator(await ws(gw, "demo-operator"), "op")
        await op.snapshot()
        robots = [TestRobot(await ws(gw, f"demo-robot-{i}"), i, move_s=0.02) for i in range(3)]
        for r in robots:
            await r.hello()
        tasks = [asyncio.create_task(r.run()) for r in robots]
        await op.send(Start)
        await asyncio.wait_for(gw.wait_done(), 20)
        for t in tasks:
            t.cancel()
    records = read_trace(tmp_path / "t.jsonl")
    report = check_trace(records)
    assert report.ok, report.errors
    assert report.actions_run == 10 and [len(r.finished) for r in robots] == [5, 3, 2]
    # every action but each robot's first was dispatched before its predecessor finished
    # (LAB_PATHS has no Type 2 edges): 2 actions per robot at start, then one per finish
    early, finished = 0, set()
    for rec in records:
        if rec["type"] == "finish":
            finished.add((rec["robot"], rec["action"]))
        elif rec["type"] == "dispatch" and rec["action"] > 0:
            early += (rec["robot"], rec["action"] - 1) not in finished
    assert early == 10 - 3


async def test_a_type2_wait_is_not_released_early() -> None:
    # robot 1's action 1 enters (1, 0), which robot 0 leaves with its action 0
    async with Gateway(make_config(dispatch_lookahead=1), clock=VirtualClock()) as gw:
        await gw.listen()
        await load(gw, DEPENDENT_PATHS)
        r0 = TestRobot(await ws(gw, "demo-robot-0"), 0)
        r1 = TestRobot(await ws(gw, "demo-robot-1"), 1)
        await r0.hello()
        await r1.hello()
        await gw.command(Start(msg_id="s", seq=1))
        assert [(await r0.expect(Action)).action_id for _ in range(2)] == ["0.0.0", "0.0.1"]
        assert (await r1.expect(Action)).action_id == "0.1.0"
        await r1.send(Started, action_id="0.1.0")
        await r1.send(Finished, action_id="0.1.0")
        await asyncio.sleep(0.2)
        assert list(gw.engine.robot(1).held) == []  # 0.1.1 waits for robot 0's action 0
        await r0.send(Started, action_id="0.0.0")
        await r0.send(Finished, action_id="0.0.0")
        assert (await r1.expect(Action)).action_id == "0.1.1"


async def test_reconnect_resends_both_held_actions_in_order() -> None:
    async with Gateway(make_config(dispatch_lookahead=1), clock=VirtualClock()) as gw:
        await gw.listen()
        await load(gw, LAB_PATHS[:1])
        robot = TestRobot(await ws(gw, "demo-robot-0"), 0, ack=False)
        await robot.hello()
        await gw.command(Start(msg_id="s", seq=1))
        first = [(await robot.expect(Action)).action_id for _ in range(2)]
        assert first == ["0.0.0", "0.0.1"]
        await robot.send(Started, action_id="0.0.0")
        await robot.link.close()  # the finished report of 0.0.0 is lost with the link
        await asyncio.wait_for(_until(lambda: gw.engine.robot(0).link is None), 5)
        held = gw.engine.robot(0).held
        assert list(held) == first and not any(h.acked for h in held.values())
        again = TestRobot(await ws(gw, "demo-robot-0"), 0)
        welcome: Welcome = await again.hello(finished=["0.0.0"])
        # 0.0.0 is applied from the hello; 0.0.1 and the newly released 0.0.2 are resent
        assert [a.action_id for a in welcome.resend] == ["0.0.1", "0.0.2"]
        assert gw.engine.robot(0).applied == {"0.0.0": "finished"}
        task = asyncio.create_task(again.run())
        await asyncio.wait_for(gw.wait_done(), 10)
        task.cancel()
        assert again.finished == [f"0.0.{i}" for i in range(1, 5)]
