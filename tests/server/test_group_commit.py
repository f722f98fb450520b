"""What makes a WMS's submissions cheap: a group commit (what the owner task finds queued
together is committed in one transaction, at most ``GROUP_COMMIT_ITEMS`` items, and nothing is
answered before its commit: the oracle for "durable" is the journal file read through a SQLite
connection of its own), and the run's collector settings: from a lifelong gateway's start, and
none during a one-shot run."""

from __future__ import annotations

import asyncio
import gc
import json
import math
import sqlite3
from pathlib import Path

import pytest

from gateway.execution.lifelong.tasks import KEEP, NewTask, TaskPool
from gateway.server import gc_tuning
from gateway.server.clock import VirtualClock
from gateway.server.engine import GROUP_COMMIT_ITEMS
from gateway.server.gateway import Gateway
from gateway.server.task_api.models import MAX_BATCH
from protocol import Pause, Resume, Start
from tests.server.conftest import LAB_PATHS, make_config
from tests.server.robots import TestRobot
from tests.server.task_client import call
from tests.server.test_end_to_end import load, ws
from tests.server.test_task_api import cells, lifelong_config

OPERATOR = {"Authorization": "Bearer demo-operator"}


def on_disk(journal: Path) -> set[int]:
    """The tasks whose ``queued`` record is committed in the journal file."""
    db = sqlite3.connect(f"file:{journal}?mode=ro", uri=True)
    try:
        rows = db.execute("SELECT body FROM records WHERE kind = 'task'").fetchall()
    finally:
        db.close()
    return {record["task"] for record in (json.loads(body) for (body,) in rows)
            if record["state"] == "queued"}


def test_a_group_of_full_batches_fits_the_task_pools_event_window() -> None:
    """The events of GROUP_COMMIT_ITEMS batches of MAX_BATCH tasks are still kept by the pool
    when they are journaled (else a group commit would drop accepted tasks' events)."""
    assert GROUP_COMMIT_ITEMS * MAX_BATCH <= KEEP


@pytest.mark.parametrize("n", [20, 2 * GROUP_COMMIT_ITEMS + 1])
async def test_submissions_queued_together_share_a_synced_commit(tmp_path: Path, n: int) -> None:
    """``n`` submissions queued in one step of the event loop: ceil(n / GROUP_COMMIT_ITEMS)
    synced commits, and each result is seen only once its task is on disk."""
    journal = tmp_path / "journal.sqlite"
    async with Gateway(lifelong_config(journal=journal)) as gw:
        assert gw.engine.journal is not None
        grid = gw.engine.lifelong.shift.grid  # type: ignore[union-attr]
        cell = grid.index(next(iter(grid.free_cells())))
        await gw.task_api.change(lambda pool, now: pool.submit([NewTask((cell,))], now))
        before = gw.engine.journal.synced_commits

        async def submit(k: int) -> None:
            def add(pool: TaskPool, now: float) -> int:
                return pool.submit([NewTask((cell,))], now, f"key-{k}")[0][0]
            task = await gw.task_api.change(add)
            assert task in on_disk(journal)

        await asyncio.gather(*(submit(k) for k in range(n)))
        assert gw.engine.journal.synced_commits - before == math.ceil(n / GROUP_COMMIT_ITEMS)


async def test_concurrent_http_submissions_are_answered_only_once_durable(
        tmp_path: Path) -> None:
    """30 WMS clients at once over real HTTP: every answer is a 201 whose task is on disk when
    the answer arrives."""
    journal = tmp_path / "journal.sqlite"
    async with Gateway(lifelong_config(journal=journal)) as gw:
        port = await gw.listen()
        cell = cells(gw, 1)[0]

        async def submit(k: int) -> None:
            reply = await call(port, "POST", "/tasks", {"errands": [cell]},
                               {**OPERATOR, "Idempotency-Key": f"wms-{k}"})
            assert reply.status == 201, reply.body
            assert reply.json()["tasks"][0]["id"] in on_disk(journal)

        await asyncio.gather(*(submit(k) for k in range(30)))


async def test_a_lifelong_gateway_collects_rarely_before_its_shift_starts() -> None:
    """A WMS filling a shift that has not started is served with the run's collector
    settings: the startup heap frozen, young passes rarely (not every 700 allocations)."""
    gc_tuning.restore_defaults()
    try:
        assert gc.get_threshold() == gc_tuning.GC_DEFAULT_THRESHOLDS
        async with Gateway(lifelong_config()) as gw:
            assert gw.engine.lifelong is not None and not gw.engine.current_run.ticking
            assert gc.get_threshold() == gc_tuning.GC_THRESHOLDS
            assert gc.get_freeze_count() > 0
    finally:
        gc_tuning.restore_defaults()


@pytest.mark.looptime
async def test_a_one_shot_run_has_no_cyclic_collection_until_it_is_complete() -> None:
    """Once a one-shot run starts, its objects are frozen and the cyclic collector is off
    until the run is complete (then the defaults are back): no pass stalls the owner task. An
    operator's pause gives it back for as long as it lasts."""
    gc_tuning.restore_defaults()
    seen: list[tuple[str, bool, bool]] = []
    try:
        async with Gateway(make_config(), clock=VirtualClock()) as gw:
            gw.engine.status_listeners.append(
                lambda status: seen.append((status, gc.isenabled(), gc.get_freeze_count() > 0)))
            await gw.listen()
            await load(gw, LAB_PATHS)
            robots = [TestRobot(await ws(gw, f"demo-robot-{i}"), i, move_s=0.02)
                      for i in range(3)]
            for r in robots:
                await r.hello()
            tasks = [asyncio.create_task(r.run()) for r in robots]
            assert gc.isenabled()  # loaded, not started: the defaults
            await gw.command(Start(msg_id="s", seq=1))
            assert not gc.isenabled() and gc.get_freeze_count() > 0
            await asyncio.sleep(0.05)
            assert (await gw.command(Pause(msg_id="p", seq=2)))[0] is None
            assert gc.isenabled() and gc.get_threshold() == gc_tuning.GC_DEFAULT_THRESHOLDS
            assert (await gw.command(Resume(msg_id="r", seq=3)))[0] is None
            assert not gc.isenabled() and gc.get_freeze_count() > 0
            await asyncio.wait_for(gw.wait_done(), 20)
            for t in tasks:
                t.cancel()
        assert ("running", False, True) in seen and ("paused", True, False) in seen
        assert seen[-1] == ("done", True, False)
        assert gc.get_threshold() == gc_tuning.GC_DEFAULT_THRESHOLDS
    finally:
        gc_tuning.restore_defaults()
