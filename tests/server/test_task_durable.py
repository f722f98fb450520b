"""Durable tasks: ``fleetgate serve`` in lifelong mode, killed with SIGKILL and restarted with
the same command line, loses no accepted task and finishes none twice (the journal rebuilds
the task book: ``GET /tasks/{id}`` shows each task as before, its idempotency key still
answers a retry; the event stream goes on with the same event ids)."""

from __future__ import annotations

import asyncio
import json
from pathlib import Path
from typing import Any

from bench.crash import GatewayProcess, free_port
from gateway.planning.lorr import warehouse_problem
from gateway.server.clock import LoopClock
from sim_clients.connect import websocket_connector
from sim_clients.fleet import SimFleet
from tests.server.task_client import call, sse

ROBOTS = 4


async def _counts(port: int) -> dict[str, int]:
    return dict((await call(port, "GET", "/tasks?limit=1")).json()["counts"])


async def _fleet(port: int) -> SimFleet:
    fleet = SimFleet(websocket_connector(f"ws://127.0.0.1:{port}/ws"), range(ROBOTS),
                     clock=LoopClock(10.0), send_state=False)
    await fleet.start()
    await fleet.wait_connected(30.0)
    return fleet


async def _until(port: int, done: Any, timeout_s: float = 90.0) -> dict[str, int]:
    async with asyncio.timeout(timeout_s):
        while not done(counts := await _counts(port)):
            await asyncio.sleep(0.1)
    return counts


def test_a_killed_gateway_keeps_every_accepted_task_and_finishes_each_once(
        tmp_path: Path) -> None:
    port = free_port()
    gw = GatewayProcess(tmp_path, port, speed=10.0, policy="none")
    config = tmp_path / "gateway.json"
    config.write_text(json.dumps({**json.loads(config.read_text()), "map": None,
                                  "autostart": True, "lifelong": {
                                      "robots": ROBOTS, "warehouse": [2, 3],
                                      "task_list": False}}))
    out: dict[str, Any] = {}

    async def main() -> None:
        gw.start()
        grid = warehouse_problem(ROBOTS, 0, (2, 3), p_delay=0.0).grid
        free = [[x, y] for x, y in grid.free_cells()]
        fleet = await _fleet(port)
        batch = {"tasks": [{"errands": [free[(5 * k) % len(free)],
                                        free[(11 * k + 3) % len(free)]]} for k in range(8)],
                 "idempotency_key": "shift-1"}
        first = await call(port, "POST", "/tasks", batch)
        ids = [t["id"] for t in first.json()["tasks"]]
        before = await _until(port, lambda c: c["finished"] >= 2)
        await fleet.stop()
        late = await call(port, "POST", "/tasks", {"errands": [free[1]]})
        assert late.status == 201  # acknowledged: it must survive what comes now
        every = [*ids, late.json()["tasks"][0]["id"]]
        out["views"] = [(await call(port, "GET", f"/tasks/{i}")).json() for i in every]
        gw.kill()
        gw.start()
        out["views_after"] = [(await call(port, "GET", f"/tasks/{i}")).json() for i in every]
        listed = (await call(port, "GET", "/tasks")).json()
        out["after_restart"] = {t["id"]: t["state"] for t in listed["tasks"]}
        retry = await call(port, "POST", "/tasks", batch)
        out["retry"] = (retry.status, [t["id"] for t in retry.json()["tasks"]])
        fleet = await _fleet(port)
        await _until(port, lambda c: c["finished"] == len(ids) + 1)
        await fleet.stop()
        events = []
        finished = 0
        async with asyncio.timeout(30):
            async for ev in sse(port, "/tasks/events?after=0"):
                events.append(ev)
                finished += ev.data["state"] == "finished"
                if finished == len(ids) + 1:
                    break
        gw.stop()
        out.update(ids=ids, late=late.json()["tasks"][0]["id"], before=before, events=events)

    try:
        asyncio.run(main())
    finally:
        gw.stop()
    ids, late = out["ids"], out["late"]
    assert sorted(out["after_restart"]) == [*ids, late]  # nothing accepted was lost
    assert out["retry"] == (200, ids)  # the idempotency key survived the restart
    finished_before = [i for i, s in out["after_restart"].items() if s == "finished"]
    assert len(finished_before) >= 2
    # GET /tasks/{id} after the restart: what was submitted and when is kept; a finished
    # or started task is shown exactly as before (its robot, errand and finish times too)
    for before, after in zip(out["views"], out["views_after"], strict=True):
        same = ("id", "errands", "priority", "deadline_ms", "idempotency_key", "submitted_ms")
        assert {k: after[k] for k in same} == {k: before[k] for k in same}
        if before["state"] in ("finished", "started"):  # a started one stays with its robot
            assert after == before
        else:
            assert after["state"] in ("queued", "assigned"), after
    by_task: dict[int, list[str]] = {}
    for ev in out["events"]:
        by_task.setdefault(ev.data["task"], []).append(ev.data["state"])
    assert [e.id for e in out["events"]] == list(range(1, len(out["events"]) + 1))
    for task in [*ids, late]:
        states = by_task[task]
        assert states.count("finished") == 1 and states[-1] == "finished", (task, states)
