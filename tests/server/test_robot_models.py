"""Robot models from the configuration: the monitor's t_x per action kind and per robot reach
the dispatched actions (real gateway, real websockets); an unknown model name is refused."""

from __future__ import annotations

import asyncio

import pytest

from gateway.server.clock import VirtualClock
from gateway.server.config import ConfigError, load_config
from gateway.server.gateway import Gateway
from protocol import Action, LoadPlan, Start
from tests.server.conftest import connector, make_config
from tests.server.robots import TestRobot
from tests.server.test_versions import TURN_HEADINGS, TURN_PATHS

pytestmark = pytest.mark.looptime  # virtual time over real websockets


async def test_each_robot_gets_its_models_durations() -> None:
    config = make_config(robot_models={"turtlebot": {"move_ms": 1500.0, "turn_ms": 2500.0}},
                         robot_model={0: "turtlebot"}, action_ms=800.0)
    async with Gateway(config, clock=VirtualClock()) as gw:
        await gw.listen()
        code, detail = await gw.command(LoadPlan(msg_id="l", seq=0, map="lab", paths=TURN_PATHS,
                                                 headings=TURN_HEADINGS))
        assert code is None, detail
        ws = connector(gw)
        robots = [TestRobot(await ws(f"demo-robot-{i}"), i) for i in (0, 1)]
        for r in robots:
            await r.hello()
        tasks = [asyncio.create_task(r.run()) for r in robots]
        assert await gw.command(Start(msg_id="s", seq=1)) == (None, "started")
        await asyncio.wait_for(gw.wait_done(), 10)
        for t in tasks:
            t.cancel()
        # robot 0 (turtlebot): move 1500, turn 2500, move 1500; robot 1: action_ms for all
        assert [[m.duration_ms for m in r.inbox if isinstance(m, Action)] for r in robots] == [
            [1500.0, 2500.0, 1500.0], [800.0, 800.0, 800.0]]
        ex = gw.engine.executor
        assert ex is not None and ex.monitor.estimated_makespan_ms() == ex.makespan_ms


def test_an_unknown_model_name_is_a_config_error() -> None:
    with pytest.raises(ConfigError, match=r"robot_model names unknown robot models \['tb3'\]"):
        load_config(robot_model={2: "tb3"})
