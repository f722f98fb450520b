"""A power cut loses the journal's last records (issue 26, defects 2 and 9): the gateway stops
mid-run, the last 1-60 records (reports and ticks: what ``synchronous=NORMAL`` may lose) are
dropped from its journal while the robots keep what they did, and a new gateway resumes. With
robots that implement only the MUST rules (no repeated ``finished``), the run completes
(nothing stuck), every action is executed once, and the trace, cut back to the journal, is one
valid run."""

from __future__ import annotations

import asyncio
from collections import Counter
from pathlib import Path
from typing import Any

import pytest
from websockets.asyncio.client import connect

from bench.faults import drop_tail
from gateway.server.gateway import Gateway
from protocol import LoadPlan, Start
from tests.server.conftest import make_config
from tests.server.robots import TestRobot
from tests.server.test_journal import running, workload
from tracecheck import check_trace, read_trace


@pytest.mark.parametrize(("k", "seed", "stop_s"), [(1, 1, 0.20), (5, 2, 0.15), (17, 3, 0.25),
                                                    (40, 4, 0.10), (60, 5, 0.20)])
def test_a_power_cut_resumes_with_must_only_robots(tmp_path: Path, k: int, seed: int,
                                                   stop_s: float) -> None:
    journal, trace = tmp_path / "journal.sqlite", tmp_path / "trace.jsonl"
    problem = workload(6, 10, seed)
    executed: Counter[tuple[int, int, int]] = Counter()
    done: dict[str, Any] = {}

    async def main() -> None:
        config, gw, port, fleet = await running(
            journal, trace, problem, must_only=True, on_event=lambda kind, p, r, i: executed.update(
                [(p, r, i)] if kind == "execute" else []))
        await asyncio.sleep(stop_s)
        await gw.stop()
        assert gw.engine.status == "running"
        done["dropped"] = drop_tail(journal, k)
        gw2 = Gateway(config.model_copy(update={"port": port}))
        await gw2.start()
        assert gw2.resumed
        await gw2.listen()
        done["summary"] = await asyncio.wait_for(gw2.wait_done(), 30)
        await fleet.stop()
        await gw2.stop()

    asyncio.run(main())
    assert done["dropped"] >= 1
    twice = [a for a, n in executed.items() if n > 1]
    assert twice == []
    records = read_trace(trace)
    report = check_trace(records)
    assert report.errors == [] and report.collisions == []
    finishes = [(r["plan"], r["robot"], r["action"]) for r in records if r["type"] == "finish"]
    assert len(finishes) == len(set(finishes)) == sum(len(p) - 1 for p in problem.plan.paths)


CROSSING = [[(0, 0), (1, 0), (2, 0), (3, 0), (4, 0)],
            [(2, 0), (2, 1), (3, 1), (4, 1), (5, 1)]]
"""On the lab map: robot 0 enters (2, 0) once robot 1 left it, so robot 0's action 1 waits for
robot 1's action 0, and with lookahead 1 its action 2 is released with it."""


async def _robot(gw: Gateway, r: int) -> TestRobot:
    link = await connect(f"ws://127.0.0.1:{gw.port}/ws", proxy=None,
                         additional_headers={"Authorization": f"Bearer demo-robot-{r}"})
    return TestRobot(link, r)


def test_catch_ups_follow_the_order_of_the_executors_dispatches(tmp_path: Path) -> None:
    """A power cut lost every record after the run's: the robots finished the whole plan, and
    robot 0 says hello before robot 1. Robot 1's catch-up releases robot 0's actions 1 and 2
    (one batch); applying robot 0's listed finish of 1 releases its action 3 while that batch
    is still being routed. The session must get 2 before 3 (the executor's order), else
    robot 0's finish of 3 is refused ("queued behind action 2") and, as a robot need not repeat
    a ``finished``, the run never completes."""
    journal, trace = tmp_path / "journal.sqlite", tmp_path / "trace.jsonl"
    config = make_config(journal=journal, trace=trace, dispatch_lookahead=1, policy="none")
    done: dict[str, Any] = {}

    async def main() -> None:
        async with Gateway(config) as gw:  # the run, executed by robots that do everything
            await gw.listen()
            code, detail = await gw.command(LoadPlan(msg_id="l", seq=0, map="lab",
                                                     paths=CROSSING))
            assert code is None, detail
            robots = [await _robot(gw, r) for r in (0, 1)]
            for robot in robots:
                await robot.hello()
            await gw.command(Start(msg_id="s", seq=1))
            working = [asyncio.ensure_future(robot.run()) for robot in robots]
            await asyncio.wait_for(gw.wait_done(), 10)
            for robot in robots:
                await robot.link.close()
            await asyncio.gather(*working)
        done["dropped"] = drop_tail(journal, 10**6)
        async with Gateway(config) as gw2:
            assert gw2.resumed
            await gw2.listen()
            for robot in robots:  # back, in this order, with every finish (no repeat later)
                again = await _robot(gw2, robot.robot_id)
                await again.hello(finished=robot.finished)
            done["summary"] = await asyncio.wait_for(gw2.wait_done(), 10)

    asyncio.run(main())
    assert done["dropped"] >= 8
    records = read_trace(trace)
    assert check_trace(records).errors == []
    finishes = [(r["robot"], r["action"]) for r in records if r["type"] == "finish"]
    assert sorted(finishes) == [(r, i) for r in (0, 1) for i in range(4)]
