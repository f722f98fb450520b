"""The gateway drives simulated VDA 5050 vehicles through a real mosquitto, through the same
sessions and executor as its websocket robots: the same plan has the same SOC (within 2%)
with either kind of robot and with a mixed fleet, every message on the broker validates
against its version's schema, the trace passes the independent checker, nobody collides, and
an intruder in a vehicle's way makes the slack policy replan through cancelOrder and a new
order."""

from __future__ import annotations

import asyncio
import json
from pathlib import Path

from gateway.server.gateway import Gateway
from sim_clients.world import INTRUDER, World
from tests.vda5050.fleets import SPEED, run_vda, run_websocket
from tests.vda5050.schemas import SCHEMA_DIR, assert_valid
from tracecheck import check_trace, read_trace

MAP, SCEN, AGENTS = "warehouse-small", "warehouse-small-random-1", 10


def _check(trace: Path) -> None:
    report = check_trace(read_trace(trace))
    assert report.ok, report.errors


async def test_ten_vehicles_and_a_mixed_fleet_match_the_websocket_run(
        broker_url: str, tmp_path: Path) -> None:
    soc_ws = await run_websocket(tmp_path / "ws.jsonl", MAP, SCEN, AGENTS)
    run = await run_vda(tmp_path / "vda.jsonl", broker_url, MAP, SCEN, AGENTS,
                        list(range(AGENTS)), versions=("2.0.0", "2.1.0"))
    assert abs(run.soc_ms - soc_ws) / soc_ws <= 0.02, (run.soc_ms, soc_ws)
    _check(tmp_path / "vda.jsonl")
    assert run.world.collisions == []
    assert all(not v.errors for v in run.vehicles)
    if (SCHEMA_DIR / "2.1.0").is_dir():
        for topic, payload in run.traffic:
            assert_valid(json.loads(payload)["version"], topic.rsplit("/", 1)[-1], payload)
    assert {json.loads(p)["version"] for _, p in run.traffic} == {"2.0.0", "2.1.0"}
    orders = [json.loads(p) for t, p in run.traffic if t.endswith("/order")]
    first = [o for o in orders if o["orderUpdateId"] == 0]
    assert len(first) == AGENTS
    # the first order's base is what the ADG released, its horizon the rest of the path
    assert any(not n["released"] for o in first for n in o["nodes"])
    assert max(o["orderUpdateId"] for o in orders) > 5
    mixed = await run_vda(tmp_path / "mixed.jsonl", broker_url, MAP, SCEN, AGENTS,
                          list(range(0, AGENTS, 2)))
    assert abs(mixed.soc_ms - soc_ws) / soc_ws <= 0.02, (mixed.soc_ms, soc_ws)
    _check(tmp_path / "mixed.jsonl")
    assert mixed.world.collisions == []


async def test_intruder_replans_through_cancel_order(broker_url: str, tmp_path: Path) -> None:
    async def intrude(gw: Gateway, world: World) -> None:
        problem = gw.engine.problem
        assert problem is not None and problem.plan is not None
        path = problem.plan.paths[0]  # robot 0 drives east along row 13 from (7, 13)
        cell = path[6]
        await asyncio.sleep(1.5 / SPEED)
        while not world.is_free(cell):
            await asyncio.sleep(0.01)
        world.occupy(cell, INTRUDER, 0.0)
        await asyncio.sleep(8 / SPEED)
        world.release(cell, INTRUDER)

    run = await run_vda(tmp_path / "t.jsonl", broker_url, MAP, SCEN, AGENTS,
                        list(range(AGENTS)), during=intrude)
    records = read_trace(tmp_path / "t.jsonl")
    assert [r["plan"] for r in records if r["type"] == "plan"] == [0, 1]
    _check(tmp_path / "t.jsonl")
    assert run.world.collisions == []
    sent = [json.loads(p) for t, p in run.traffic if t.endswith("/instantActions")]
    cancels = [m for m in sent if m["actions"][0]["actionType"] == "cancelOrder"]
    assert cancels, "the replan cancelled orders"
    orders = [json.loads(p) for t, p in run.traffic if t.endswith("/order")]
    new = [o for o in orders if o["orderId"].split(".")[0] == "1" and o["orderUpdateId"] == 0]
    assert new and all(o["nodes"][0]["sequenceId"] == 0 for o in new)
