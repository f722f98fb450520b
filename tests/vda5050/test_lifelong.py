"""A lifelong shift with a mixed fleet through a real mosquitto: three simulated VDA 5050
vehicles and three websocket-protocol robots in one shift, one live ADG. The vehicles' errands
are nodes with ``pick`` / ``drop`` actions (blocking HARD), and an errand is done when its
node action is: the errands the task pool counts for each vehicle are exactly the node actions
that vehicle finished, none ran twice, the trace passes tracecheck, nobody collides and every
message on the broker validates against the schemas."""

from __future__ import annotations

import asyncio
import json
from collections import Counter
from pathlib import Path

from gateway.server.config import GatewayConfig, LifelongSettings
from gateway.server.gateway import Gateway
from gateway.vda5050.transport import VdaTransport
from protocol.messages import StopShift
from sim_clients.fleet import SimFleet
from sim_clients.shift import stop_shift
from sim_clients.vda_fleet import (
    driven_actions,
    make_vehicles,
    run_fleet,
    shift_starts,
    vda_config,
)
from tests.vda5050.fleets import sniff
from tests.vda5050.schemas import SCHEMA_DIR, assert_valid
from tracecheck import check_trace, read_trace

ROBOTS, VDA = 6, [0, 2, 4]
SPEED = 4.0


async def test_mixed_lifelong_shift_picks_and_drops(broker_url: str, tmp_path: Path) -> None:
    vda = vda_config(broker_url, VDA, ("2.0.0", "2.1.0"))
    config = GatewayConfig(port=0, speed=SPEED, trace=tmp_path / "t.jsonl", log_level="WARNING",
                           map=None, autostart=True, dispatch_lookahead=1, vda5050=vda,
                           lifelong=LifelongSettings(robots=ROBOTS, warehouse=(2, 3)))
    seen: list[tuple[str, bytes]] = []
    sniffing = asyncio.Event()
    sniffer = asyncio.create_task(sniff(vda.broker, seen, sniffing))
    await sniffing.wait()
    async with Gateway(config) as gw:
        websocket = [r for r in range(ROBOTS) if r not in VDA]
        fleet = SimFleet(gw.connect, websocket, clock=gw.clock, send_state=False)
        vehicles = make_vehicles(vda, fleet.world, speed=SPEED, starts=shift_starts(config))
        stop = asyncio.Event()
        driving = asyncio.create_task(run_fleet(vehicles, vda.broker, stop))
        async with VdaTransport(gw, vda):
            await fleet.start()
            await fleet.wait_connected(30)
            shift = gw.engine.lifelong
            assert shift is not None
            async with asyncio.timeout(60):
                while shift.status == "loaded" or gw.engine.now_ms() < 40_000.0:
                    await asyncio.sleep(0.05)
            stats = await stop_shift(gw, fleet)
            await fleet.stop()
        stop.set()
        await driving
        pool = shift.executor.pool
    await asyncio.sleep(0.2)
    sniffer.cancel()
    assert stats.duplicated == 0 and stats.collisions == 0
    records = read_trace(tmp_path / "t.jsonl")
    report = check_trace(records)
    assert report.ok, report.errors
    # every action dispatched to a vehicle was driven, once, and its finish is in the trace
    driven = Counter((v.who, number) for v in vehicles for number in driven_actions(v))
    assert driven and max(driven.values()) == 1, (
        [k for k, n in driven.items() if n > 1],
        [(v.who, v.driven[-12:]) for v in vehicles])
    for kind in ("dispatch", "finish"):
        assert {(r["robot"], r["action"]) for r in records
                if r["type"] == kind and r["robot"] in VDA} == set(driven), kind
    # the pool's errands of each vehicle are the picks and drops it finished, each once
    done = Counter[int]()
    for task in pool.book.values():
        done[task.robot] += task.done
    for v in vehicles:
        assert len(set(v.node_actions_run)) == len(v.node_actions_run)
        assert len(v.node_actions_run) == done[v.who], v.who
        assert all(a.action_status == "FINISHED" for a in v.action_states.values()
                   if a.action_type in ("pick", "drop"))
        assert not v.errors
    assert sum(done[r] for r in VDA) >= 3 and sum(done[r] for r in websocket) >= 3
    orders = [json.loads(p) for t, p in seen if t.endswith("/order")]
    kinds = {a["actionType"] for o in orders for n in o["nodes"] for a in n["actions"]}
    assert kinds == {"pick", "drop"}
    assert all(a["blockingType"] == "HARD" for o in orders for n in o["nodes"]
               for a in n["actions"])
    # segments extend the vehicle's order: far fewer orders than order messages
    assert len({o["orderId"] for o in orders}) < len(orders)
    if (SCHEMA_DIR / "2.1.0").is_dir():
        for topic, payload in seen:
            assert_valid(json.loads(payload)["version"], topic.rsplit("/", 1)[-1], payload)


async def test_a_vehicles_failed_pick_cancels_its_task(broker_url: str, tmp_path: Path) -> None:
    # vehicle 0's picks all FAIL (section 6.8.2: e.g. the station is empty): each failed
    # pick's task is cancelled as DELETE /tasks/<id> would (none of its errands is done), the
    # vehicle's action finishes (it drove it) and the vehicle goes on with other tasks; the
    # other vehicles finish theirs
    robots = [0, 1, 2]
    vda = vda_config(broker_url, robots, ("2.1.0",))
    config = GatewayConfig(port=0, speed=SPEED, trace=tmp_path / "t.jsonl", log_level="WARNING",
                           map=None, autostart=True, dispatch_lookahead=1, vda5050=vda,
                           lifelong=LifelongSettings(robots=len(robots), warehouse=(2, 3)))
    async with Gateway(config) as gw:
        vehicles = make_vehicles(vda, None, speed=SPEED, starts=shift_starts(config))
        vehicles[0].fail_actions = {"pick"}
        stop = asyncio.Event()
        driving = asyncio.create_task(run_fleet(vehicles, vda.broker, stop))
        async with VdaTransport(gw, vda):
            shift = gw.engine.lifelong
            assert shift is not None
            async with asyncio.timeout(60):
                while shift.status == "loaded" or gw.engine.now_ms() < 40_000.0:
                    await asyncio.sleep(0.05)
            await gw.command(StopShift(msg_id="shift-stop", seq=1))
            await asyncio.wait_for(gw.wait_done(), 60.0)
        stop.set()
        await driving
        pool = shift.executor.pool
    failed = vehicles[0].node_actions_run
    assert failed and all(a.startswith("pick-") for a in failed)
    cancelled = {t.id for t in pool.book.values() if t.state == "cancelled"}
    assert cancelled == {int(a.split("-t")[1].split(".")[0]) for a in failed}
    events = [e for e in pool.events if e.task in cancelled and e.state == "cancelled"]
    assert len(events) == len(cancelled)  # each cancelled once, on the event stream
    # it drove on after its first failed pick; the others' tasks finished
    assert len(vehicles[0].driven) > 2 * len(failed)
    assert any(t.state == "finished" for t in pool.book.values())
    assert all(not v.errors for v in vehicles)
    report = check_trace(read_trace(tmp_path / "t.jsonl"))
    assert report.ok, report.errors
