"""The journal: replay rebuilds the executor, its monitor and the robot sessions field by field,
a restarted gateway resumes the run, and action ids never repeat across runs or restarts."""

from __future__ import annotations

import asyncio
import json
import random
import sqlite3
import time
from array import array
from collections import deque
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from pydantic import TypeAdapter

from gateway.execution.oneshot.executor import Mode
from gateway.execution.oneshot.policies import POLICY_NAMES, PolicyName, make_policy
from gateway.planning.instance import Instance
from gateway.planning.plan import Plan
from gateway.planning.random_plans import open_grid, random_plan
from gateway.runtime.journal import Journal, RunRecord, ShadowRecord, SnapshotRecord, TimeRecord
from gateway.server.clock import VirtualClock, run_virtual
from gateway.server.config import GatewayConfig
from gateway.server.engine import Engine
from gateway.server.gateway import Gateway
from gateway.server.planner import Problem
from protocol import Pause, ReplanNow, Resume, action_run
from sim_clients.connect import websocket_connector
from sim_clients.fleet import SimFleet, fleet_for, run_in_process
from sim_clients.intruder import IntruderConfig
from tracecheck import check_trace, read_trace

SKIP = {"_record", "sink", "_out", "link", "_np_state", "_np_remaining", "_np_ts", "_np_tc",
        "_np_delta", "_np_tx", "_graph"}
"""Callbacks, the drained command buffer, connections, and numpy views of compared arrays."""


def differences(a: Any, b: Any, where: str = "", out: list[str] | None = None) -> list[str]:
    """Where two object graphs differ (attribute paths), walked field by field."""
    out = [] if out is None else out
    if len(out) > 10:
        return out
    if type(a) is not type(b):
        out.append(f"{where}: {type(a).__name__} != {type(b).__name__}")
    elif isinstance(a, np.ndarray):
        if not np.array_equal(a, b, equal_nan=True):
            out.append(f"{where}: arrays differ")
    elif isinstance(a, array | bytearray | bytes | str | int | float | bool | type(None)):
        same = a == b or (isinstance(a, float) and a != a and b != b)
        if isinstance(a, array) and a.typecode == "d":
            same = np.array_equal(np.array(a), np.array(b), equal_nan=True)
        if not same:
            out.append(f"{where}: {str(a)[:80]} != {str(b)[:80]}")
    elif isinstance(a, list | tuple | deque):
        if len(a) != len(b):
            out.append(f"{where}: length {len(a)} != {len(b)}")
        for i, (x, y) in enumerate(zip(a, b, strict=False)):
            differences(x, y, f"{where}[{i}]", out)
    elif isinstance(a, set | frozenset):
        if a != b:
            out.append(f"{where}: {sorted(a ^ b)[:5]} differ")
    elif isinstance(a, dict):
        if a.keys() != b.keys():
            out.append(f"{where}: keys {sorted(set(a) ^ set(b))[:5]} differ")
        for k in a.keys() & b.keys():
            differences(a[k], b[k], f"{where}[{k!r}]", out)
    elif isinstance(a, random.Random):
        if a.getstate() != b.getstate():
            out.append(f"{where}: random state differs")
    elif hasattr(a, "__dict__") or hasattr(a, "__slots__"):
        fields = dict(vars(a)) if hasattr(a, "__dict__") else {}
        for slot in getattr(type(a), "__slots__", ()):
            if hasattr(a, slot):
                fields[slot] = getattr(a, slot)
        for k, v in fields.items():
            if k not in SKIP and not callable(v):
                differences(v, getattr(b, k), f"{where}.{k}", out)
    elif a != b:
        out.append(f"{where}: {a!r} != {b!r}")
    return out


def workload(robots: int = 8, steps: int = 12, seed: int = 3) -> Problem:
    plan = random_plan(open_grid(8, 8), robots, steps, random.Random(seed))
    grid = open_grid(8, 8)
    starts = tuple(p[0] for p in plan.paths)
    goals = tuple(p[-1] for p in plan.paths)
    return Problem(Instance(grid, starts, goals, "open"), "open", plan)


async def assert_rebuilt(live: Engine, config: GatewayConfig) -> None:
    """A second gateway on a copy of ``live``'s journal (one writer per journal; and no trace
    file) rebuilds its executor, monitor, robot sessions, policy, intruders and replan marks,
    field by field."""
    assert live.executor is not None and config.journal is not None
    copy = config.journal.with_name("copy.sqlite")
    copy.unlink(missing_ok=True)
    with sqlite3.connect(config.journal) as src, sqlite3.connect(copy) as dst:
        src.backup(dst)
    async with Gateway(config.model_copy(update={"port": 0, "trace": None, "journal": copy}),
                       clock=VirtualClock()) as other:
        again = other.engine
        assert other.resumed or live.executor.mode is Mode.DONE
        assert again.executor is not None
        assert again.run_id == live.run_id
        diff = differences(live.executor, again.executor, "executor")
        assert diff == [], diff
        for r, gs in live.robots.items():
            diff = differences(gs, again.robot(r), f"robot{r}", [])
            # what only a connection tells: acknowledgements, poses, versions
            diff = [d for d in diff if ".acked" not in d and ".pose" not in d]
            assert diff == [], diff
        assert again.feed.intruders == live.feed.intruders
        assert again.feed.replan_marks == live.feed.replan_marks
        assert (again.policy_name, again.threshold_ms) == (live.policy_name, live.threshold_ms)
        assert again.solvers.solver_ms == live.solvers.solver_ms
        assert again.paused == live.paused


async def running(journal: Path, trace: Path, problem: Problem, *, must_only: bool = False,
                  on_event: Callable[[str, int, int, int], None] | None = None
                  ) -> tuple[GatewayConfig, Gateway, int, SimFleet]:
    """A journaled gateway at speed 20 on a free port running ``problem`` with a simulated
    fleet over websockets (``must_only``: robots that implement only the MUST rules;
    ``on_event``: the fleet's hook)."""
    config = GatewayConfig(port=0, map=None, policy="none", journal=journal, trace=trace,
                           speed=20.0, autostart=True)
    gw = Gateway(config)
    await gw.start()
    port = await gw.listen()
    fleet = SimFleet(websocket_connector(f"ws://127.0.0.1:{port}/ws"),
                     range(len(problem.plan.paths)), clock=gw.clock, send_state=False,
                     reconnect_delay_s=0.05, must_only=must_only)
    fleet.on_event = on_event
    gw.engine.load(problem)
    await fleet.start()
    await fleet.wait_connected()
    return config, gw, port, fleet


def lanes(robots: int, width: int) -> Problem:
    """Robot i crosses an open grid along row 2i (a long run that a replan cannot shorten)."""
    grid = open_grid(width, 2 * robots)
    plan = Plan.of([[(x, 2 * r) for x in range(width)] for r in range(robots)])
    return Problem(Instance(grid, tuple(p[0] for p in plan.paths),
                            tuple(p[-1] for p in plan.paths), "lanes"), "lanes", plan)


@pytest.mark.parametrize("policy", ["random", "shadow"])
def test_replay_rebuilds_the_executor_monitor_and_sessions_field_by_field(
        policy: PolicyName, tmp_path: Path) -> None:
    """At several moments of a run with an intruder and a replan (shadow: background solves
    too), a second engine that replays the journal equals the running one in every field."""
    journal = tmp_path / "journal.sqlite"
    checked: list[tuple[float, int, int]] = []

    async def main() -> None:
        config = GatewayConfig(port=0, map=None, policy=policy, policy_seed=2,
                               journal=journal, dispatch_lookahead=1)
        async with Gateway(config, clock=VirtualClock()) as gw:
            # (an intruder early and long enough for shadow's background solves)
            fleet = fleet_for(gw, 8, gw.connect, intruder=True, seed=1,
                              intruder_config=IntruderConfig(appear_ms=1000, leave_ms=8000))
            run = asyncio.ensure_future(run_in_process(gw, workload(), fleet))
            while gw.status != "running":
                await asyncio.sleep(0.01)
            for _ in range(14):
                await asyncio.sleep(0.93)
                if run.done():
                    break
                live = gw.engine
                assert live.executor is not None
                await assert_rebuilt(live, config)
                checked.append((live.executor.now_ms, live.executor.plan_id,
                                live.executor.replans))
            await run
            await fleet.stop()

    run_virtual(main())
    assert len(checked) >= 5
    if policy == "shadow":  # background solves came back (and were replayed), with plans
        assert [r for r in Journal(journal).records()
                if isinstance(r, ShadowRecord) and r.paths is not None]
    else:
        assert any(plan >= 1 for _, plan, _ in checked), "the run never replanned"


def test_a_journal_compacted_at_every_replan_stays_bounded_and_resumes_exactly(
        tmp_path: Path) -> None:
    """Twenty operator replans (one adopted during a pause) in a run with an intruder: each
    adoption replaces the journal's records by one snapshot, so the journal holds only the
    current plan's records, and a gateway resuming from a snapshot (and the records after
    it) equals the live one field by field; the live trace is one valid run."""
    journal, trace = tmp_path / "journal.sqlite", tmp_path / "trace.jsonl"
    counts: list[tuple[int, int]] = []  # (records in the journal, records appended so far)

    async def main() -> None:
        config = GatewayConfig(port=0, map=None, policy="operator", max_replans=20,
                               journal=journal, trace=trace)
        async with Gateway(config, clock=VirtualClock()) as gw:
            fleet = fleet_for(gw, 8, gw.connect, intruder=True, seed=4)
            run = asyncio.ensure_future(run_in_process(gw, lanes(8, 40), fleet))
            while gw.status != "running":
                await asyncio.sleep(0.01)
            live = gw.engine
            assert live.executor is not None and live.journal is not None
            ex, replans = live.executor, 0
            while not run.done() and ex.replans < 20:
                await asyncio.sleep(0.7)
                if gw.status != "running":
                    continue
                paused = ex.replans == 5
                plan = ex.plan_id
                assert (await gw.command(ReplanNow(msg_id="r", seq=0)))[0] is None
                if paused:
                    assert (await gw.command(Pause(msg_id="p", seq=0)))[0] is None
                while ex.plan_id == plan and not run.done():
                    await asyncio.sleep(0.05)
                if paused:
                    await assert_rebuilt(live, config)  # a plan adopted during the pause
                    assert (await gw.command(Resume(msg_id="q", seq=0)))[0] is None
                replans += 1
                await asyncio.sleep(0.3)  # records after the snapshot
                records = list(live.journal.records())
                assert isinstance(records[0], SnapshotRecord)
                assert records[0].plan_id == ex.plan_id
                counts.append((len(records), live.journal.appended))
                if replans % 4 == 0:
                    await assert_rebuilt(live, config)
            await run
            await fleet.stop()

    run_virtual(main())
    assert len(counts) >= 12, counts
    appended = counts[-1][1]
    assert max(n for n, _ in counts) < appended / 5, (counts, appended)
    records = read_trace(trace)
    report = check_trace(records)
    assert report.errors == [] and report.collisions == []
    plans = [r["plan"] for r in records if r["type"] == "plan"]
    assert plans == list(range(len(plans))) and len(plans) > len(counts)


def test_every_policy_state_fits_a_snapshot() -> None:
    """A snapshot journals a policy by its attributes: every policy's are plain values that
    come back equal (a policy with richer state would need its own field)."""
    field = SnapshotRecord.model_fields["policy_state"]
    for name in POLICY_NAMES:
        state = dict(vars(make_policy(name, seed=3, makespan_lb_ms=90_000.0)))
        again = TypeAdapter(field.annotation).validate_json(json.dumps(state))
        assert again == state and [type(v) for v in again.values()] == [
            type(v) for v in state.values()], name


def test_action_ids_carry_the_run_and_never_repeat_across_runs_or_restarts(
        tmp_path: Path) -> None:
    journal = tmp_path / "journal.sqlite"
    runs: list[str] = []

    async def main() -> None:
        for _ in range(2):  # a restart: a new Gateway on the same journal
            config = GatewayConfig(port=0, map=None, policy="none", journal=journal)
            async with Gateway(config, clock=VirtualClock(), fresh=True) as gw:
                for _ in range(2):  # two runs in one process
                    fleet = fleet_for(gw, 3, gw.connect, intruder=False)
                    await run_in_process(gw, workload(3, 4), fleet)
                    await fleet.stop()
                    held = [aid for gs in gw.engine.robots.values() for aid in gs.applied]
                    assert held and {action_run(a) for a in held} == {gw.engine.run_id}
                    runs.append(gw.engine.run_id)
                    records = list(Journal(journal).records())
                    assert isinstance(records[0], RunRecord)
                    assert records[0].run_id == gw.engine.run_id

    run_virtual(main())
    assert len(set(runs)) == 4 and all(runs)


def test_a_restarted_gateway_resumes_the_run_and_the_trace_is_appended(
        tmp_path: Path) -> None:
    """In one process: the gateway stops mid-run (its fleet keeps its state), a new gateway on
    the same journal resumes, the robots reconnect and the run completes with every action
    executed once; the trace is one valid run."""
    journal, trace = tmp_path / "journal.sqlite", tmp_path / "trace.jsonl"
    problem = workload(6, 10, 5)
    done: dict[str, Any] = {}

    async def main() -> None:
        config, gw, port, fleet = await running(journal, trace, problem)
        await asyncio.sleep(0.25)  # speed 20: 5 s of plan time
        await gw.stop()
        size = trace.stat().st_size
        assert gw.engine.status == "running" and size > 0
        gw2 = Gateway(config.model_copy(update={"port": port}))
        await gw2.start()
        assert gw2.resumed
        assert trace.stat().st_size >= size  # appended to, never truncated
        await gw2.listen()
        done["summary"] = await asyncio.wait_for(gw2.wait_done(), 20)
        done["dups"] = fleet.stats.duplicates
        done["errors"] = list(fleet.stats.errors)
        await fleet.stop()
        await gw2.stop()

    asyncio.run(main())
    records = read_trace(trace)
    report = check_trace(records)
    assert report.errors == [] and report.collisions == []
    finishes = [(r["plan"], r["robot"], r["action"]) for r in records if r["type"] == "finish"]
    assert len(finishes) == len(set(finishes)) == sum(len(p) - 1 for p in problem.plan.paths)
    assert done["errors"] == []


if __name__ == "__main__":
    pytest.main([__file__, "-q"])


def test_under_continuous_commits_the_wal_starts_over_and_stays_bounded(tmp_path: Path) -> None:
    """Commits never pause long enough for a passive checkpoint to catch up; the checkpointer
    has the writer catch up the last frames, so the WAL starts over and is trimmed to its
    bound, and every record is kept."""
    path = tmp_path / "j.sqlite"
    journal = Journal(path, checkpoint_period_s=0.005, wal_bound_pages=40)
    page = 4096  # SQLite's default page size
    n, deadline = 0, time.monotonic() + 60.0
    while journal.restarts < 3 and time.monotonic() < deadline:
        journal.append(TimeRecord(kind="tick", t_ms=float(n)))
        journal.commit()  # one frame or more per commit
        n += 1
    assert journal.restarts >= 3, journal.restarts
    cp = journal.checkpointer
    assert cp is not None and cp.max_wal_pages > 40
    cp.stop()  # no pass in the way of the next commit
    grown = journal.wal_bytes()
    journal.append(TimeRecord(kind="tick", t_ms=float(n)))
    journal.commit()  # the WAL starts over: the file is trimmed to the bound
    assert journal.wal_bytes() <= 40 * page < grown
    journal.close()
    again = Journal(path)
    assert [r.t_ms for r in again.records() if isinstance(r, TimeRecord)] == [
        float(i) for i in range(n + 1)]
    again.close()


def test_a_resumed_trace_gets_the_missing_tail_and_loses_a_torn_line(tmp_path: Path) -> None:
    from gateway.server.operator_feed import OperatorFeed

    trace = tmp_path / "t.jsonl"
    whole = [f'{{"t_ms":{i},"type":"tick"}}\n' for i in range(5)]
    trace.write_text("".join(whole[:2]) + whole[2][:7])  # a crash tore record 2
    feed = OperatorFeed(10, trace)
    feed.resume_trace(whole)
    feed.write_trace({"t_ms": 5, "type": "tick"})
    feed.close_trace()
    assert trace.read_text() == "".join(whole) + '{"t_ms":5,"type":"tick"}\n'
    feed.new_run()  # a new run moves the old trace aside, never truncates it
    feed.close_trace()
    assert (tmp_path / "t.jsonl.1").read_text().count("\n") == 6
    assert trace.read_text() == ""


def test_serve_refuses_fresh_without_a_journal_and_an_unusable_journal(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from gateway.cli import main

    assert main(["serve", "--port", "0", "--no-journal", "--fresh"]) == 2
    assert "--no-journal excludes" in capsys.readouterr().err
    blocker = tmp_path / "file"
    blocker.write_text("")
    assert main(["serve", "--port", "0", "--journal", str(blocker / "j.sqlite")]) == 2
    err = capsys.readouterr().err
    assert "cannot open the journal" in err and "Traceback" not in err
