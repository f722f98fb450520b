"""The task API's one clock (issue 27 item 5), over real HTTP with a shift of simulated robots
on real websockets: a task posted before the robots are there is at 0 of the shift's clock,
never after its own assignment, and every ``*_ms`` has its wall-clock ``*_at`` beside it."""

from __future__ import annotations

import asyncio
import time
from datetime import datetime
from typing import Any

from gateway.server.gateway import Gateway
from sim_clients.connect import websocket_connector
from sim_clients.fleet import SimFleet
from sim_clients.shift import start_shift, stop_shift
from tests.server.task_client import call, sse
from tests.server.test_task_api import ROBOTS, cells, lifelong_config


def wall(iso: str) -> float:
    """POSIX seconds of an ``*_at`` (ISO 8601, UTC, ``Z``)."""
    assert iso.endswith("Z"), iso
    return datetime.fromisoformat(iso).timestamp()


def test_every_task_time_is_on_the_shift_clock_with_its_wall_time() -> None:
    out: dict[str, Any] = {}

    async def main() -> None:
        async with Gateway(lifelong_config(speed=1.0)) as gw:
            port = await gw.listen()
            a, b, c = cells(gw, 3)
            await asyncio.sleep(1.5)  # the gateway's own clock runs; no shift yet
            early = await call(port, "POST", "/tasks", {"errands": [a, b],
                                                        "deadline_ms": 60_000})
            out["early"] = early.json()["tasks"][0]
            out["before"] = (await call(port, "GET", "/tasks")).json()
            fleet = SimFleet(websocket_connector(f"ws://127.0.0.1:{port}/ws"), range(ROBOTS),
                             clock=gw.clock, send_state=False)
            out["wall_before_start"] = time.time()
            await start_shift(gw, fleet)
            out["wall_after_start"] = time.time()
            task_id = out["early"]["id"]
            async with asyncio.timeout(60):
                while (await call(port, "GET", f"/tasks/{task_id}")).json()["state"] in (
                        "queued", "paused"):
                    await asyncio.sleep(0.05)
            await asyncio.sleep(0.5)
            out["posted_at"] = time.time()
            out["late"] = (await call(port, "POST", "/tasks", {"errands": [c]})).json()[
                "tasks"][0]
            out["listing"] = (await call(port, "GET", "/tasks")).json()
            out["listed_at"] = time.time()
            events = []
            async with asyncio.timeout(10):
                async for ev in sse(port, "/tasks/events?after=0"):
                    events.append(ev.data)
                    if ev.id >= out["listing"]["last_event"]:
                        break
            out["events"] = events
            await stop_shift(gw, fleet)
            await fleet.stop()

    asyncio.run(main())
    early, before = out["early"], out["before"]
    # before the shift: its clock reads 0, and its wall time is not known yet
    assert early["submitted_ms"] == 0.0 and early["submitted_at"] is None
    assert (early["deadline_ms"], early["deadline_at"]) == (60_000.0, None)
    assert (before["now_ms"], before["now_at"]) == (0.0, None)
    listing = out["listing"]
    task = next(t for t in listing["tasks"] if t["id"] == early["id"])
    assert task["state"] != "queued"
    assert 0.0 == task["submitted_ms"] <= task["assigned_ms"] <= listing["now_ms"]
    start = wall(task["submitted_at"])  # 0 is the shift's start
    assert out["wall_before_start"] - 0.01 <= start <= out["wall_after_start"] + 0.01
    for ms, at in (("assigned_ms", "assigned_at"), ("deadline_ms", "deadline_at")):
        assert abs(wall(task[at]) - start - task[ms] / 1000.0) < 0.002, (ms, task)
    assert [round(wall(x) - start, 3) for x in task["errand_at"]] == \
        [round(t / 1000.0, 3) for t in task["errand_ms"]]
    late = out["late"]
    assert late["submitted_ms"] > 0.0
    assert abs(wall(late["submitted_at"]) - out["posted_at"]) < 0.5  # speed 1: wall time
    assert abs(wall(listing["now_at"]) - out["listed_at"]) < 0.5
    for ev in out["events"]:
        assert abs(wall(ev["at"]) - start - ev["t_ms"] / 1000.0) < 0.002, ev
        assert 0.0 <= ev["t_ms"] <= listing["now_ms"]
