"""The run contract (:class:`gateway.server.runs.base.Run`) as a suite any run must pass, through
a real gateway in virtual time with simulated robots on in-memory links: ``check_run(make)``.

``make()`` gives the configuration of a gateway whose run is loaded and not started
(``autostart`` off) and what to load into it (a one-shot plan; nothing for a shift). The
checks go through the operators' commands only: start, start again (refused), pause (nothing
starts any more: the count of applied finishes stops growing), resume (it grows again),
"replan now" (accepted), and what the run reports on the way (status, its core's pause). Then
the run goes on to its end: a one-shot run's last action (then "stop the shift" is refused),
a shift's plan time ``END_MS`` and the operator's "stop the shift" (once). The suite runs
twice: once uninterrupted, once with a crash after "replan now" (the run is journaled: a
second gateway started on a copy of the journal takes over at the same virtual instant and the
robots reconnect to it); the two runs' cores at the end are equal field by field
(:func:`plain`): a shift's included, as its planner keeps no state of its own between calls
(PIBT's priorities travel with each request and come back with each journaled segment, the
random stream is the call's), so a restarted planner process plans what the first would
have."""

from __future__ import annotations

import asyncio
import enum
import math
import random
import sqlite3
import tempfile
from array import array
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from gateway.server.clock import VirtualClock, run_virtual
from gateway.server.config import GatewayConfig
from gateway.server.gateway import Gateway
from gateway.server.planner import Problem
from gateway.server.wire.transport import MemoryClient
from protocol import ErrorCode, Pause, ReplanNow, Resume, Start, StopShift
from sim_clients.fleet import SimFleet


@dataclass(frozen=True)
class RunSetup:
    """A gateway configuration (autostart off), its fleet's size and what to load (None: the
    run is loaded by the configuration)."""

    config: GatewayConfig
    robots: int
    problem: Problem | None = None


NOT_STATE = {"_record", "sink", "_out", "link", "grid", "distances", "scheduler", "leg",
             "space", "_graph", "_np_state", "_np_remaining", "_np_ts", "_np_tc",
             "_np_delta", "_np_tx"}
"""Callbacks, drained output, configuration and caches (a rebuilt run has its own), and
numpy views of compared arrays."""

HEAPS = {"_thresholds"}
"""Binary heaps: compared by their sorted contents (the same entries pushed in another order
lie differently and pop in the same order)."""


def plain(obj: Any, path: frozenset[int] = frozenset()) -> Any:
    """Every field of ``obj``, recursively, as plain comparable values (NaN as a string)."""
    if id(obj) in path:
        return "<cycle>"
    inner = path | {id(obj)}
    match obj:
        case None | bool() | int() | str():
            return obj
        case float():
            return "nan" if math.isnan(obj) else obj
        case enum.Enum():
            return obj.value
        case np.ndarray():
            return plain(obj.tolist(), inner)
        case list() | tuple() | deque() | bytearray() | array():
            return [plain(x, inner) for x in obj]
        case set() | frozenset():
            return sorted((plain(x, inner) for x in obj), key=repr)
        case dict():
            return [(plain(k, inner), plain(v, inner)) for k, v in obj.items()]
        case random.Random():
            return obj.getstate()
        case _ if hasattr(obj, "__dict__") or hasattr(obj, "__slots__"):
            fields = dict(vars(obj)) if hasattr(obj, "__dict__") else {}
            for slot in getattr(type(obj), "__slots__", ()):
                if hasattr(obj, slot):
                    fields[slot] = getattr(obj, slot)
            return {k: plain(sorted(v) if k in HEAPS else v, inner)
                    for k, v in fields.items() if k not in NOT_STATE and not callable(v)}
    return repr(obj)


Make = Callable[[], RunSetup]
SOLVER_MS = 120.0
"""Virtual time a planner call is charged."""
END_MS = 30_000.0
"""Where a shift's run is compared (plan time)."""


def _finished(gw: Gateway) -> float:
    """Action finishes the engine applied so far (its public metrics)."""
    return gw.metrics.value("fleetgate_actions_finished_total")


class _Router:
    """The fleet's connector: a robot (re)connects to whichever gateway is up now."""

    def __init__(self, gw: Gateway) -> None:
        self.gw = gw

    async def __call__(self, token: str) -> MemoryClient:
        return await self.gw.connect(token)


async def _crash(gw: Gateway, setup: RunSetup, journal: Path, router: _Router) -> Gateway:
    """Crash ``gw`` now: a gateway on a copy of its journal (what a crash now leaves) takes
    over at the same virtual instant, the robots reconnect to it; it resumed the same run."""
    copy = journal.with_name("copy.sqlite")
    with sqlite3.connect(journal) as src, sqlite3.connect(copy) as dst:
        src.backup(dst)
    config = setup.config.model_copy(update={"port": 0, "trace": None, "journal": copy})
    other = Gateway(config, clock=VirtualClock(solver_time=SOLVER_MS))
    live = plain(gw.engine.current_run.core)
    await other.start()  # (inline: no virtual time passes)
    assert other.resumed and other.engine.run_id == gw.engine.run_id
    assert plain(other.engine.current_run.core) == live
    router.gw = other
    await gw.stop()  # its links close: the robots reconnect to the resumed one
    for _ in range(8):  # the takeover's work at this instant (no virtual time passes)
        await other.clock.settle()
    core = other.engine.current_run.core
    assert core is not None
    wake = core.next_wakeup_ms()
    assert wake is None or wake > other.clock.now_ms()  # nothing due is put off to a tick
    return other


async def _quiet(gw: Gateway) -> None:
    """Step on until the run has no planner call under way (a crash in the middle of one
    plans it again later than the live run had it: a different, equally valid future)."""
    while gw.engine.current_run.planner_busy:
        await asyncio.sleep(0.01)


async def _check(setup: RunSetup, journal: Path, crash: bool) -> Any:
    """The contract's checks, then the run to its end (a one-shot run's last action; a
    shift's plan time ``END_MS``), crashing and resuming in the middle if ``crash``; the run's
    core at the end, field by field (:func:`plain`)."""
    config = setup.config.model_copy(update={"journal": journal})
    gw = Gateway(config, clock=VirtualClock(solver_time=SOLVER_MS))
    await gw.start()
    router = _Router(gw)
    if setup.problem is not None:
        gw.engine.load(setup.problem)
    fleet = SimFleet(router, range(setup.robots), clock=gw.clock, send_state=False,
                     reconnect_delay_s=0.0)
    try:
        await fleet.start()
        await fleet.wait_connected(60)
        run = gw.engine.current_run
        assert gw.status == "loaded" and not run.ticking
        assert await gw.command(Start(msg_id="s1", seq=0)) == (None, "started")
        assert gw.status == "running" and run.ticking and run.core is not None
        code, _ = await gw.command(Start(msg_id="s2", seq=1))
        assert code is ErrorCode.BAD_STATE  # a run starts once
        await asyncio.sleep(4.0)
        assert _finished(gw) > 0
        assert await gw.command(Pause(msg_id="p", seq=2)) == (None, "paused")
        assert gw.status == "paused" and run.core.paused
        await asyncio.sleep(3.0)  # what was under way finishes
        frozen = _finished(gw)
        await asyncio.sleep(3.0)
        assert _finished(gw) == frozen  # nothing new started while paused
        assert await gw.command(Resume(msg_id="r", seq=3)) == (None, "resumed")
        assert gw.status in ("running", "replanning") and not run.core.paused
        await asyncio.sleep(4.0)
        assert _finished(gw) > frozen
        code, _ = await gw.command(ReplanNow(msg_id="n", seq=4))
        assert code is None
        await asyncio.sleep(1.0)
        await _quiet(gw)
        if crash:
            gw = await _crash(gw, setup, journal, router)
        at_crash = _finished(gw)
        stop = StopShift(msg_id="x", seq=5)
        if setup.problem is not None:
            await gw.wait_done()
            code, _ = await gw.command(stop)
            assert code is ErrorCode.BAD_STATE  # a one-shot run has no shift to stop
        else:
            await gw.clock.sleep_until_ms(END_MS)
            assert await gw.command(stop) == (None, "stopping the shift")
            await gw.wait_done()  # once every robot finished what it was dispatched
            code, _ = await gw.command(stop)
            assert code is ErrorCode.BAD_STATE  # stopped once
        assert _finished(gw) > at_crash  # it went on
        return plain(gw.engine.current_run.core)
    finally:
        await fleet.stop()
        await gw.stop()


def check_run(make: Make) -> None:
    """Run every check of the contract on a fresh gateway from ``make``, once without and
    once with a crash in the middle: the resumed run equals the live one at the crash, and
    the two runs end equal field by field."""
    ends = []
    for crash in (False, True):
        with tempfile.TemporaryDirectory() as tmp:
            ends.append(run_virtual(_check(make(), Path(tmp) / "journal.sqlite", crash)))
    assert ends[1] == ends[0]
