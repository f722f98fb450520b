"""Reschedule-first in the gateway: with the ``reschedule`` policy, a robot passes a slow one
over real (in-memory) connections in virtual time, without a stop or a replan."""

from __future__ import annotations

import asyncio
from pathlib import Path

from gateway.server.clock import VirtualClock, run_virtual
from gateway.server.gateway import Gateway
from protocol import LoadPlan, Start
from tests.server.conftest import make_config
from tests.server.robots import TestRobot
from tracecheck import check_trace, read_trace

# Robot 0 crosses (4,1) in its actions 1-2; robot 1 waits above it and enters after.
CROSSING = [[(2, 1), (3, 1), (4, 1), (5, 1), (6, 1)],
            [(4, 0), (4, 0), (4, 0), (4, 0), (4, 1), (4, 2)]]


async def _run(trace: Path, policy: str) -> tuple[float, float]:
    """Robot 0 takes 6 s per action, robot 1 1 s; the SOC and makespan."""
    async with Gateway(make_config(trace=trace, policy=policy), clock=VirtualClock()) as gw:
        await gw.command(LoadPlan(msg_id="l", seq=0, map="lab", paths=CROSSING))
        robots = [TestRobot(await gw.connect(f"demo-robot-{i}"), i, move_s=s)
                  for i, s in enumerate((6.0, 1.0))]
        for r in robots:
            await r.hello()
        tasks = [asyncio.create_task(r.run()) for r in robots]
        await gw.command(Start(msg_id="s", seq=1))
        soc, makespan = await gw.wait_done()
        for t in tasks:
            t.cancel()
        return soc, makespan


def test_the_gateway_lets_a_robot_pass_a_slow_one(tmp_path: Path) -> None:
    # Without rescheduling robot 1 waits until robot 0 has crossed (4,1) at 18 s: it ends at
    # 20 s, robot 0 at 24 s. Rescheduled, robot 1 crosses first and ends at 5 s.
    assert run_virtual(_run(tmp_path / "none.jsonl", "none")) == (44_000.0, 24_000.0)
    assert run_virtual(_run(tmp_path / "r.jsonl", "reschedule")) == (29_000.0, 24_000.0)
    records = read_trace(tmp_path / "r.jsonl")
    report = check_trace(records)
    assert report.ok, report.errors
    assert report.plans == 1  # no replan
    switches = [r["switches"] for r in records if r["type"] == "reschedule"]
    assert switches == [[[[4, 1], 1, 0]]]
