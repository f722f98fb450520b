"""Clocks: virtual time runs a whole asyncio system (gateway + in-memory robots) exactly and
reproducibly; speed changes keep time continuous; the planner's time is charged as told."""

from __future__ import annotations

import asyncio
import json
import time
from collections.abc import Awaitable, Callable
from pathlib import Path

import pytest

from gateway.server.clock import PACE_PERIOD_S, RealClock, VirtualClock, run_paced, run_virtual
from gateway.server.gateway import Gateway
from gateway.server.items import Inbound
from protocol import IntruderReport, LoadPlan, Start
from tests.server.conftest import LAB_PATHS, make_config
from tests.server.robots import TestRobot
from tracecheck import check_trace, read_trace


async def _run_lab(trace: Path, meanwhile: Callable[[Gateway], Awaitable[None]] | None = None,
                   ) -> tuple[float, float, float]:
    """Three robots run the lab plan in virtual time (``meanwhile`` is awaited after the
    start); the SOC, the makespan and the time at the end."""
    async with Gateway(make_config(trace=trace), clock=VirtualClock()) as gw:
        await gw.command(LoadPlan(msg_id="l", seq=0, map="lab", paths=LAB_PATHS))
        robots = [TestRobot(await gw.connect(f"demo-robot-{i}"), i, move_s=1.0)
                  for i in range(3)]
        for r in robots:
            await r.hello()
        tasks = [asyncio.create_task(r.run()) for r in robots]
        await gw.command(Start(msg_id="s", seq=1))
        if meanwhile is not None:
            await meanwhile(gw)
        soc, makespan = await gw.wait_done()
        for t in tasks:
            t.cancel()
        return soc, makespan, gw.clock.now_ms()


def test_virtual_time_is_exact_and_reproducible(tmp_path: Path) -> None:
    first = run_virtual(_run_lab(tmp_path / "a.jsonl"))
    # every action takes 1000 ms and no robot waits: SOC = (5 + 3 + 2) x 1000, makespan 5000
    assert first[:2] == (10000.0, 5000.0)
    assert first[2] == 5000.0
    second = run_virtual(_run_lab(tmp_path / "b.jsonl"))
    assert second == first
    a = [json.loads(x) for x in (tmp_path / "a.jsonl").read_text().splitlines()]
    b = [json.loads(x) for x in (tmp_path / "b.jsonl").read_text().splitlines()]
    assert a == b and a[-1] == {"type": "summary", "soc_ms": 10000.0, "makespan_ms": 5000.0}


def test_virtual_clock_charges_the_solver_as_configured() -> None:
    async def charged(solver_time: float | str) -> tuple[int, float, float]:
        clock = VirtualClock(solver_time=solver_time)  # type: ignore[arg-type]
        clock.reset()
        result, ms = await clock.run_solver(lambda: 6 * 7)
        return result, ms, clock.now_ms()

    assert run_virtual(charged(750.0)) == (42, 750.0, 750.0)
    assert run_virtual(charged("zero")) == (42, 0.0, 0.0)
    result, ms, now = run_virtual(charged("measured"))
    assert result == 42 and ms >= 0.0
    # the loop's resolution is 1 µs, and both the sleep's deadline and now are rounded to it
    assert now == pytest.approx(ms, abs=0.002)


def test_paced_virtual_time_is_exact_and_never_runs_ahead_of_the_wall_clock() -> None:
    # the loop sees exact virtual times; the wall clock takes at least as long (less one
    # pacing period for the phase); a period the process was starved for (here: the loop
    # blocked for 0.3 s) is not made up by running faster afterwards
    async def main() -> tuple[float, float, float, float]:
        loop = asyncio.get_running_loop()
        t0, w0 = loop.time(), time.monotonic()
        await asyncio.sleep(0.5)
        t1, w1 = loop.time(), time.monotonic()
        time.sleep(0.3)  # starved: the loop's virtual time stands still meanwhile
        w2 = time.monotonic()
        await asyncio.sleep(0.2)
        return t1 - t0, w1 - w0, loop.time() - t1, time.monotonic() - w2

    virtual_a, wall_a, virtual_b, wall_b = run_paced(main())
    assert (virtual_a, virtual_b) == (pytest.approx(0.5, abs=1e-6), pytest.approx(0.2, abs=1e-6))
    assert wall_a >= 0.5 - PACE_PERIOD_S
    assert wall_b >= 0.2 - PACE_PERIOD_S


def test_speed_change_keeps_plan_time_continuous() -> None:
    async def scenario() -> list[float]:
        clock = VirtualClock(speed=1.0)
        clock.reset()
        await asyncio.sleep(1.0)           # 1000 ms of plan time at speed 1
        clock.set_speed(4.0)
        seen = [clock.now_ms()]
        await asyncio.sleep(0.5)           # 0.5 s of loop time = 2000 ms at speed 4
        seen.append(clock.now_ms())
        await clock.sleep_until_ms(5000.0)  # 1000 ms more plan time = 0.25 s of loop time
        seen.append(clock.now_ms())
        return seen

    assert run_virtual(scenario()) == [1000.0, 3000.0, 5000.0]


async def test_virtual_clock_refuses_a_real_loop() -> None:
    with pytest.raises(RuntimeError, match="looptime"):
        VirtualClock().reset()
    with pytest.raises(ValueError, match="positive"):
        RealClock().set_speed(0.0)


async def test_real_clock_runs_the_solver_in_a_thread() -> None:
    import threading

    clock = RealClock()
    clock.reset()
    main = threading.get_ident()
    worker, _ = await clock.run_solver(threading.get_ident)
    assert worker != main


async def _intruder_handled_late(gw: Gateway) -> None:
    await gw.connect("demo-world")
    await gw.clock.sleep_until_ms(1250.0)  # the monitor ticked at 1200 ms
    [world] = [s for s in gw.sessions if s.peer.role == "world"]
    # what a busy owner task sees: a report that arrived at 1210 ms, handled at 1250 ms
    report = IntruderReport(msg_id="i", seq=0, cell=(8, 1), state="on")
    gw.engine.queue.put_nowait(Inbound(world, report, time.perf_counter(), 1210.0))


def test_an_intruder_report_takes_effect_when_it_arrived(tmp_path: Path) -> None:
    # Stamped when the owner task handled it, an intruder report came after robot reports that
    # arrived later but carry their arrival time: the trace's time went backwards (CI, stop 8).
    trace = tmp_path / "t.jsonl"
    run_virtual(_run_lab(trace, _intruder_handled_late))
    records = read_trace(trace)
    [on] = [r for r in records if r["type"] == "intruder"]
    assert on["t_ms"] == 1210.0
    assert check_trace(records).errors == []


async def _monitor_fails_for_a_while(gw: Gateway) -> None:
    ex = gw.engine.executor
    assert ex is not None
    tick = ex.tick

    def failing_tick(now_ms: float) -> None:
        if 1000.0 <= now_ms < 2000.0:
            raise RuntimeError("monitor bug")
        tick(now_ms)

    ex.tick = failing_tick  # type: ignore[method-assign]


def test_a_failing_monitor_tick_is_logged_once_and_the_run_goes_on(
        tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    # An exception in a tick used to end the owner task silently: the fleet stalled.
    soc, makespan, _ = run_virtual(_run_lab(tmp_path / "t.jsonl", _monitor_fails_for_a_while))
    assert (soc, makespan) == (10000.0, 5000.0)  # the plan's times: robots were never held
    failures = [r for r in caplog.records if r.getMessage() == "internal error in the monitor tick"]
    assert len(failures) == 1  # ten failing ticks (every 100 ms for 1 s), one log record
