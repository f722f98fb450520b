"""Protocol v2 serves v1 robots (real gateway, real websockets): each connection speaks the
version of its robot's hello; only a v2 robot may report a move stopped on the way."""

from __future__ import annotations

import asyncio

import pytest

from gateway.planning.validate import check_plan
from protocol import (
    Action,
    Blocked,
    ErrorCode,
    Finished,
    Hello,
    LoadInstance,
    LoadPlan,
    Start,
    Started,
    Unblocked,
)
from tests.server.conftest import LAB_PATHS, virtual_gateway
from tests.server.robots import TestRobot


@pytest.mark.looptime  # virtual time over real websockets
async def test_each_robot_is_answered_in_its_version() -> None:
    async with virtual_gateway() as (gateway, ws_connect):
        code, detail = await gateway.command(LoadPlan(msg_id="l", seq=0, map="lab",
                                                      paths=LAB_PATHS))
        assert code is None, detail
        old = TestRobot(await ws_connect("demo-robot-0"), 0)
        new = TestRobot(await ws_connect("demo-robot-1"), 1)
        assert (await old.hello(v=1)).v == 1
        assert (await new.hello()).v == 3
        assert await gateway.command(Start(msg_id="s", seq=1)) == (None, "started")
        a_old, a_new = await old.expect(Action), await new.expect(Action)
        assert (a_old.v, a_new.v) == (1, 3)
        assert a_old.src.heading is None and a_new.dst.heading is None  # an omni plan
        # a v1 robot's bumper stop after started is refused (v1: blocked = target cell taken)
        await old.send(Started, v=1, action_id=a_old.action_id)
        ref = await old.send(Blocked, v=1, action_id=a_old.action_id)
        err = await old.error_for(ref)
        assert (err.v, err.code) == (1, ErrorCode.REJECTED)
        assert "already started" in err.detail
        # a v2 robot's is a stop on the way: accepted, and the move goes on when it clears
        await new.send(Started, action_id=a_new.action_id)
        await new.send(Blocked, action_id=a_new.action_id)
        await new.send(Unblocked, action_id=a_new.action_id)
        await new.send(Finished, action_id=a_new.action_id)
        nxt = await new.expect(Action)
        assert nxt.action_id == "0.1.1"
        ex = gateway.engine.executor
        assert ex is not None and ex.robot_cell(1) == LAB_PATHS[1][1]
        assert [e for e in new.inbox if e.type == "error"] == []


TURN_PATHS = [[(0, 0), (1, 0), (1, 0), (1, 1)], [(5, 1), (5, 1), (5, 1), (4, 1)]]
TURN_HEADINGS = [[0, 0, 1, 1], [0, 1, 2, 2]]
"""Robot 0 drives east, turns south and drives on; robot 1 turns twice (to west) and drives."""


@pytest.mark.looptime  # virtual time over real websockets
async def test_a_turning_plan_sends_poses_with_headings_and_refuses_v1() -> None:
    async with virtual_gateway() as (gateway, ws_connect):
        code, detail = await gateway.command(LoadPlan(msg_id="l", seq=0, map="lab",
                                                      paths=TURN_PATHS, headings=TURN_HEADINGS))
        assert code is None, detail
        old = TestRobot(await ws_connect("demo-robot-1"), 1)
        ref = await old.send(Hello, v=1, robot_id=1)
        err = await old.error_for(ref)
        assert (err.v, err.code) == (1, ErrorCode.UNSUPPORTED_VERSION) and "v2" in err.detail
        robots = [TestRobot(await ws_connect(f"demo-robot-{i}"), i, move_s=0.02) for i in (0, 1)]
        for r in robots:
            await r.hello()
        tasks = [asyncio.create_task(r.run()) for r in robots]
        assert await gateway.command(Start(msg_id="s", seq=1)) == (None, "started")
        await asyncio.wait_for(gateway.wait_done(), 10)
        for t in tasks:
            t.cancel()
        sent = [[(m.src.cell, m.src.heading, m.dst.cell, m.dst.heading) for m in r.inbox
                 if isinstance(m, Action)] for r in robots]
        assert sent == [[((0, 0), "E", (1, 0), "E"), ((1, 0), "E", (1, 0), "S"),
                         ((1, 0), "S", (1, 1), "S")],
                        [((5, 1), "E", (5, 1), "S"), ((5, 1), "S", (5, 1), "W"),
                         ((5, 1), "W", (4, 1), "W")]]


@pytest.mark.looptime  # virtual time over real websockets
async def test_an_illegal_turning_plan_is_refused() -> None:
    async with virtual_gateway() as (gateway, _):
        code, detail = await gateway.command(LoadPlan(
            msg_id="l", seq=0, map="lab", paths=TURN_PATHS, headings=[[0, 0, 2, 2], [0, 1, 2, 2]]))
        assert code is ErrorCode.BAD_REQUEST
        assert detail == ("invalid plan: robot 0 action 1: turn from heading 0 to 2 on (1, 0): "
                          "a turn is 90 degrees")


@pytest.mark.looptime  # virtual time over real websockets
async def test_the_gateway_plans_turning_by_default() -> None:
    """Real robots turn: the gateway's own plans are turning plans unless configured otherwise,
    every robot of a MovingAI scenario starting east; the planning validator accepts them."""
    async with virtual_gateway() as (gateway, _):
        assert gateway.config.motion == "turning"
        code, detail = await gateway.command(LoadInstance(msg_id="i", seq=0, map="lab",
                                                          scen="lab-random-1", agents=3))
        assert code is None, detail
        problem = gateway.engine.problem
        assert problem is not None and problem.plan is not None
        plan, inst = problem.plan, problem.instance
        assert plan.headings is not None and [h[0] for h in plan.headings] == [0, 0, 0]
        check_plan(inst.grid, inst.turning_starts(), inst.goals, plan)
