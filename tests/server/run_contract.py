"""The run contract (:class:`gateway.server.runs.base.Run`) as a suite any run must pass, through
a real gateway in virtual time with simulated robots on in-memory links: ``check_run(make)``.

``make()`` gives the configuration of a gateway whose run is loaded and not started
(``autostart`` off) and what to load into it (a one-shot plan; nothing for a shift). The
checks go through the operators' commands only: start, start again (refused), pause (nothing
starts any more: the count of applied finishes stops growing), resume (it grows again),
"replan now" (accepted), and what the run reports on the way (status, its core's pause). The
run is journaled: at the end a second gateway started on a copy of the journal (a crash there)
resumes the run, and its core equals the live one at the crash field by field (:func:`plain`)."""

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
from protocol import ErrorCode, Pause, ReplanNow, Resume, Start
from sim_clients.fleet import SimFleet


@dataclass(frozen=True)
class RunSetup:
    """A gateway configuration (autostart off), its fleet's size and what to load (None: the
    run is loaded by the configuration)."""

    config: GatewayConfig
    robots: int
    problem: Problem | None = None


NOT_STATE = {"_record", "sink", "_out", "link", "grid", "distances", "scheduler", "leg",
             "space", "_layer_cache", "_np_state", "_np_remaining", "_np_ts", "_np_tc",
             "_np_delta", "_np_tx"}
"""Callbacks, drained output, configuration and caches (a rebuilt run has its own), and
numpy views of compared arrays."""


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
            return {k: plain(v, inner) for k, v in fields.items()
                    if k not in NOT_STATE and not callable(v)}
    return repr(obj)


Make = Callable[[], RunSetup]


def _finished(gw: Gateway) -> float:
    """Action finishes the engine applied so far (its public metrics)."""
    return gw.metrics.value("fleetgate_actions_finished_total")


async def _crash_and_resume(gw: Gateway, setup: RunSetup, journal: Path) -> None:
    """A gateway on a copy of ``gw``'s journal (as after a crash now) resumes the same run:
    its core equals the live one's at the crash."""
    copy = journal.with_name("copy.sqlite")
    with sqlite3.connect(journal) as src, sqlite3.connect(copy) as dst:
        src.backup(dst)
    live = plain(gw.engine.current_run.core)  # (the live run goes on meanwhile)
    config = setup.config.model_copy(update={"port": 0, "trace": None, "journal": copy})
    async with Gateway(config, clock=VirtualClock(solver_time=120.0)) as other:
        assert other.resumed and other.engine.run_id == gw.engine.run_id
        again = plain(other.engine.current_run.core)
        assert again == live


async def _check(setup: RunSetup, journal: Path) -> None:
    config = setup.config.model_copy(update={"journal": journal})
    async with Gateway(config, clock=VirtualClock(solver_time=120.0)) as gw:
        if setup.problem is not None:
            gw.engine.load(setup.problem)
        fleet = SimFleet(gw.connect, range(setup.robots), clock=gw.clock, send_state=False)
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
            await _crash_and_resume(gw, setup, journal)
        finally:
            await fleet.stop()


def check_run(make: Make) -> None:
    """Run every check of the contract on a fresh gateway from ``make``."""
    with tempfile.TemporaryDirectory() as tmp:
        run_virtual(_check(make(), Path(tmp) / "journal.sqlite"))
