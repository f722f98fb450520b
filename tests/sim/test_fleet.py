"""The simulated fleet over real transports: duplicate actions, reconnection, the intruder,
and ``fleetgate sim`` against a gateway over websockets."""

from __future__ import annotations

import argparse
import asyncio
import signal
import subprocess
import sys
from pathlib import Path
from typing import Any

from gateway.planning.plan import Plan
from gateway.planning.random_plans import open_grid
from gateway.server.clock import VirtualClock, run_virtual
from gateway.server.config import GatewayConfig
from gateway.server.gateway import Gateway
from gateway.server.planner import Problem
from gateway.server.wire.auth import Peer
from gateway.server.wire.transport import MemoryClient, MemoryLink, memory_pair
from protocol import (
    Ack,
    Action,
    AnyMessage,
    Finished,
    Hello,
    PlaceIntruder,
    Pose,
    Started,
    Welcome,
    decode,
    encode,
)
from sim_clients.connect import websocket_connector
from sim_clients.des import PolicyName
from sim_clients.fleet import SimFleet, fleet_for, run_in_process
from tracecheck import check_trace, read_trace

CORRIDOR = Plan.of([[(0, 0), (1, 0), (2, 0), (3, 0), (4, 0)],
                    [(0, 2), (1, 2), (2, 2), (3, 2)]])
"""Two robots walking right on rows 0 and 2 of a 5x3 open grid (no shared cell)."""


def problem(plan: Plan = CORRIDOR) -> Problem:
    """The plan on the 5x3 open grid."""
    from gateway.planning.instance import Instance

    grid = open_grid(5, 3)
    return Problem(Instance(grid, tuple(p[0] for p in plan.paths),
                            tuple(p[-1] for p in plan.paths), "open"), "open", plan)


class FakeGateway:
    """The gateway end of one robot's in-memory link, driven by hand."""

    def __init__(self, link: MemoryLink) -> None:
        self.link = link
        self.seq = 0

    async def send(self, kind: type[AnyMessage], **fields: Any) -> None:
        self.seq += 1
        await self.link.send(encode(kind(msg_id=f"g-{self.seq}", seq=self.seq, **fields)))

    async def recv(self) -> AnyMessage:
        return decode(await self.link.recv())


def test_duplicate_actions_are_dropped_unacknowledged_in_v3() -> None:
    async def main() -> tuple[list[AnyMessage], int]:
        links: list[MemoryLink] = []

        async def connect(token: str) -> MemoryClient:
            client, link = memory_pair(Peer("robot", 0))
            links.append(link)
            return client

        fleet = SimFleet(connect, [0], clock=VirtualClock(), send_state=False)
        fleet.clock.reset()
        await fleet.start()
        while not links:
            await asyncio.sleep(0)
        gw = FakeGateway(links[0])
        assert isinstance(await gw.recv(), Hello)
        await gw.send(Welcome, robot_id=0, start=Pose(cell=(0, 0)), plan=0)
        action = {"action_id": "0.0.0", "sequence": 0, "src": Pose(cell=(0, 0)),
                  "dst": Pose(cell=(1, 0)), "duration_ms": 1000.0}
        await gw.send(Action, **action)
        await gw.send(Action, **action)  # e.g. resent after a reconnect
        got: list[AnyMessage] = []
        async with asyncio.timeout(5):  # virtual seconds
            while not any(isinstance(m, Finished) for m in got):
                got.append(await gw.recv())
        await asyncio.sleep(3)  # nothing more comes: the duplicate is not executed again
        while not gw.link._pipe.to_gateway.empty():  # drain what was sent
            got.append(await gw.recv())
        duplicates = fleet.stats.duplicates
        await fleet.stop()
        return got, duplicates

    got, duplicates = run_virtual(main())
    kinds = [type(m).__name__ for m in got]
    assert kinds.count("Ack") == 0  # protocol v3: started acknowledges it, a copy gets nothing
    assert kinds.count("Started") == 1 and kinds.count("Finished") == 1
    assert duplicates == 1
    finished = next(m for m in got if isinstance(m, Finished))
    assert finished.pose is not None and finished.pose.cell == (1, 0)
    assert all(isinstance(m, Ack | Started | Finished) for m in got)


def test_a_robot_whose_link_drops_reconnects_and_the_run_completes(tmp_path: Path) -> None:
    trace = tmp_path / "trace.jsonl"

    async def main() -> tuple[float, int, list[str]]:
        config = GatewayConfig(port=0, map=None, policy="none", trace=trace)
        async with Gateway(config, clock=VirtualClock()) as gw:
            fleet = fleet_for(gw, 2, gw.connect, intruder=False)
            fleet.reconnect_delay_s = 0.8

            async def cut() -> None:  # mid-action, twice, robot 0 then robot 1
                await asyncio.sleep(1.5)
                await fleet.robots[0].drop_link()
                await asyncio.sleep(0.9)
                await fleet.robots[1].drop_link()

            fleet_task = asyncio.ensure_future(run_in_process(gw, problem(), fleet))
            async with asyncio.timeout(5):
                while gw.status != "running":  # starts at this instant (virtual time 0)
                    await asyncio.sleep(0)
            await cut()
            result = await fleet_task
            await fleet.stop()
            return result.soc_ms, fleet.stats.reconnects, fleet.stats.errors

    soc, reconnects, errors = run_virtual(main())
    assert reconnects == 2
    assert errors == []
    # Robot 0 (4 moves) loses its link at 1500 ms in its action 1 and is back at 2300 ms: the
    # finish it made at 2000 ms while away comes in its hello, so it ends at 4300 ms. Robot 1
    # (3 moves) is cut at 2400 ms, finishes at 3000 ms alone, is back at 3200 ms: ends 3200.
    assert soc == 4300.0 + 3200.0
    report = check_trace(read_trace(trace))
    assert report.errors == [] and report.collisions == []
    assert report.soc_ms == soc


def test_a_robot_retries_a_handshake_cut_off_by_a_stopping_gateway() -> None:
    """LIVE-1: a gateway that stops (on a journal failure it ends at once) just as a robot
    reconnects closes the connection before any HTTP response. The robot must keep
    reconnecting; it gave up for good ("did not receive a valid HTTP response"), so under load
    a robot of a must-only fleet never came back and its run hung (bench/faults.py eio_sync)."""

    async def main() -> int:
        cut = 0

        async def stopping(_r: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
            nonlocal cut
            cut += 1
            writer.close()  # the request is read by nobody: no response at all

        stub = await asyncio.start_server(stopping, "127.0.0.1", 0)
        port = stub.sockets[0].getsockname()[1]
        fleet = SimFleet(websocket_connector(f"ws://127.0.0.1:{port}/ws"), range(2),
                         send_state=False, reconnect_delay_s=0.02, must_only=True)
        await fleet.start()
        try:
            async with asyncio.timeout(30):
                while cut < 4:
                    await asyncio.sleep(0.01)
            stub.close()
            await stub.wait_closed()
            async with Gateway(GatewayConfig(port=port, map=None)) as gw:
                await gw.listen()
                await fleet.wait_connected(timeout=30)
        finally:
            await fleet.stop()
        return cut

    assert asyncio.run(main()) >= 4


def test_the_world_blocks_a_robot_whose_cell_the_intruder_holds(tmp_path: Path) -> None:
    trace = tmp_path / "trace.jsonl"

    async def main() -> float:
        config = GatewayConfig(port=0, map=None, policy="none", trace=trace)
        async with Gateway(config, clock=VirtualClock()) as gw:
            fleet = fleet_for(gw, 2, gw.connect, intruder=False)
            run = asyncio.ensure_future(run_in_process(gw, problem(), fleet))
            async with asyncio.timeout(5):
                while gw.status != "running":  # starts at this instant (virtual time 0)
                    await asyncio.sleep(0)
            # robot 0 enters (2, 0) with its action 1 at 1000 ms; the intruder holds it from
            # now (0 ms) for 2500 ms
            err, detail = await gw.command(PlaceIntruder(msg_id="p", seq=0, cell=(2, 0),
                                                         duration_ms=2500.0))
            assert err is None, detail
            result = await run
            await fleet.stop()
            return result.soc_ms

    soc = run_virtual(main())
    records = read_trace(trace)
    blocked = [r for r in records if r["type"] == "blocked"]
    assert [(r["robot"], r["action"], r["t_ms"]) for r in blocked] == [(0, 1, 1000.0)]
    start = next(r for r in records if r["type"] == "start" and r["robot"] == 0
                 and r["action"] == 1)
    # the robot looks again every 100 ms; the intruder leaves at 2500 ms, after the robot's
    # look at that instant (the discrete-event driver's order), so the robot goes at 2600 ms
    assert start["t_ms"] == 2600.0
    assert [r["state"] for r in records if r["type"] == "intruder"] == ["on", "off"]
    # robot 0 arrives 1600 ms late; robot 1 is not delayed
    assert soc == 1000 * CORRIDOR.soc + 1600.0
    report = check_trace(records)
    assert report.errors == [] and report.collisions == []


def test_fleetgate_sim_drives_a_gateway_over_websockets() -> None:
    async def main() -> tuple[float, int]:
        config = GatewayConfig(port=0, map=None, policy="none", speed=20.0, autostart=True)
        async with Gateway(config) as gw:
            gw.engine.load(problem())
            port = await gw.listen()
            proc = await asyncio.create_subprocess_exec(
                sys.executable, "-m", "gateway", "sim", "--connect",
                f"ws://127.0.0.1:{port}/ws", "--robots", "2",
                stderr=subprocess.PIPE)
            try:
                soc, _ = await asyncio.wait_for(gw.wait_done(), 60)
            finally:
                proc.send_signal(signal.SIGINT)
                await asyncio.wait_for(proc.wait(), 30)
            return soc, proc.returncode or 0

    soc, code = asyncio.run(main())
    assert code == 130  # stopped by Ctrl-C (SIGINT), cleanly: the documented exit code
    # speed 20 (the robots learn it on the world connection): an action takes 50 ms of wall
    # time plus loopback round trips (each ms of those is 20 ms of plan time, more on a loaded
    # machine); at the wrong speed (1) each action would take 1000 ms of wall time, 20000 ms
    # of plan time: at least 20x the plan's cost, whatever the load
    assert 1000 * CORRIDOR.soc <= soc < 20 * 1000 * CORRIDOR.soc


def test_the_shadow_policy_goes_around_a_reported_block_through_the_gateway(
        tmp_path: Path) -> None:
    """Without replanning robot 0 waits for the intruder; with the shadow policy (and a
    gateway that has seen blocks that long before, often enough to trust that this one is
    not about to end) it goes around."""
    trace = tmp_path / "trace.jsonl"

    async def main(policy: PolicyName) -> float:
        config = GatewayConfig(port=0, map=None, policy=policy, trace=trace, motion="omni",
                               block_history_ms=[7100.0] * 19)
        async with Gateway(config, clock=VirtualClock()) as gw:
            fleet = fleet_for(gw, 2, gw.connect, intruder=False)
            run = asyncio.ensure_future(run_in_process(gw, problem(), fleet))
            async with asyncio.timeout(5):
                while gw.status != "running":
                    await asyncio.sleep(0)
            # robot 0 wants (2, 0) at 1000 ms; the intruder holds it for 8 s
            err, detail = await gw.command(PlaceIntruder(msg_id="p", seq=0, cell=(2, 0),
                                                         duration_ms=8000.0))
            assert err is None, detail
            result = await run
            await fleet.stop()
            return result.soc_ms

    waited = run_virtual(main("none"))
    assert waited == 1000 * CORRIDOR.soc + 7100.0  # robot 0 goes at 8100 ms
    soc = run_virtual(main("shadow"))
    records = read_trace(trace)
    report = check_trace(records)
    assert report.errors == [] and report.collisions == []
    assert report.soc_ms == soc
    # the block was reported, the background solve came back with a way around it, and the
    # replan needed no stop-and-solve: robot 0 went around while the intruder stayed
    (trigger,) = [r for r in records if r["type"] == "trigger"]
    assert trigger["policy"] == "shadow" and trigger["t_ms"] < 8000.0
    assert report.plans == 2
    (new,) = [r for r in records if r["type"] == "plan" and r["plan"] == 1]
    assert [2, 0] not in new["agents"][0]["path"]  # around, not through
    assert not [r for r in records if r["type"] == "blocked" and r["plan"] == 1]
    assert soc < waited


def test_fleetgate_sim_speaks_the_latest_protocol_by_default() -> None:
    from protocol.messages import PROTOCOL_VERSION
    from sim_clients.cmd_sim import register

    parser = argparse.ArgumentParser()
    register(parser.add_subparsers())
    args = parser.parse_args(["sim", "--connect", "ws://127.0.0.1:1/ws"])
    assert args.protocol == PROTOCOL_VERSION
    assert parser.parse_args(["sim", "--protocol", "2"]).protocol == 2
