"""An operator on a lifelong shift, over real websockets on 127.0.0.1: connected before the
shift starts, it gets the shift's ``plan`` event, then snapshots of the live map (the
warehouse, each robot's committed path from where the gateway has it, its task's errands)
that move on as the shift runs. The snapshot is checked against the executor and the task
pool themselves."""

from __future__ import annotations

import asyncio
from itertools import pairwise

import pytest

from gateway.server.clock import VirtualClock
from gateway.server.config import LifelongSettings
from gateway.server.gateway import Gateway
from gateway.server.views import PATH_AHEAD, snapshot_fields
from protocol import Event, GetSnapshot, Snapshot
from sim_clients.fleet import SimFleet
from sim_clients.shift import start_shift
from tests.server.conftest import connector, make_config
from tests.server.robots import Peer

pytestmark = pytest.mark.looptime  # virtual time over real websockets

ROBOTS = 6


async def test_an_operator_sees_the_shift_live() -> None:
    config = make_config(autostart=True, speed=10.0, map=None, dispatch_lookahead=1,
                         lifelong=LifelongSettings(robots=ROBOTS, warehouse=(2, 3)))
    async with Gateway(config, clock=VirtualClock()) as gw:
        await gw.listen()
        connect = connector(gw)
        operator = Peer(await connect("demo-operator"), "op")
        loaded: Snapshot = await operator.expect(Snapshot)
        assert loaded.lifelong and loaded.status == "loaded" and loaded.rows
        assert [r.cell for r in loaded.robots] == [p[0] for p in loaded.paths]
        fleet = SimFleet(connect, range(ROBOTS), clock=gw.clock, send_state=False)
        await start_shift(gw, fleet)
        plan: Event = await operator.expect(Event)
        while plan.event != "plan":
            plan = await operator.expect(Event)
        assert plan.paths is not None and len(plan.paths) == ROBOTS
        while gw.engine.now_ms() < 5000.0:
            await asyncio.sleep(0.05)
        # the snapshot is the executor's and the pool's state (read in one go: no await)
        lifelong = gw.engine.lifelong
        assert lifelong is not None
        ex, grid = lifelong.executor, lifelong.shift.grid
        snap = snapshot_fields(gw.engine.read_model())
        assert snap["lifelong"] and snap["path_offsets"] == ex.adg.done
        with_task = 0
        for r, (path, view) in enumerate(zip(snap["paths"], snap["robots"], strict=True)):
            assert path[0] == grid.cell(ex.cell[r]) == view.cell
            assert len(path) == 1 + min(ex.adg.pending(r), PATH_AHEAD)
            assert all(abs(a[0] - b[0]) + abs(a[1] - b[1]) <= 1
                       for a, b in pairwise(path))
            task = ex.pool.tasks.get(view.task) if view.task is not None else None
            if task is not None:
                with_task += 1
                assert task.robot == r
                assert view.errands == [grid.cell(c) for c in task.errands[task.done:]]
                assert view.goal == view.errands[0]
            else:
                assert view.errands == [] and all(t.robot != r
                                                  for t in ex.pool.tasks.values())
        assert with_task >= 1
        # over the wire, the map moves on
        await operator.send(GetSnapshot)
        before: Snapshot = await operator.expect(Snapshot)
        assert before.t_ms >= 5000.0  # the shift's clock
        await asyncio.sleep(1.0)
        await operator.send(GetSnapshot)
        after: Snapshot = await operator.expect(Snapshot)
        assert sum(after.path_offsets) > sum(before.path_offsets)
        assert [r.cell for r in after.robots] != [r.cell for r in before.robots]
        await fleet.stop()
