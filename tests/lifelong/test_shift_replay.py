"""Replaying a lifelong shift's journal rebuilds it field by field: a shift driven in virtual
time (robots with jittered durations and stops, planner answers after a random latency, task
API changes and operator pauses at random moments) journals its inputs into a real SQLite
journal; at random points and at the end, a fresh executor fed the committed records must equal
the live one in every field (executor, live ADG, errand book, task pool).

Snapshots too: at the same random points the live shift's state is snapshotted
(:func:`~gateway.execution.lifelong.shift_state.snapshot_shift`, through the journal record's
JSON); a
fresh executor restored from it must equal the live one field by field, and after the records
that followed it (the journal a compaction there would have left) the live one at the end."""

from __future__ import annotations

import contextlib
import copy
import dataclasses
import enum
import multiprocessing
import os
import random
import signal
import sqlite3
import tempfile
from collections import deque
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st
from pydantic import TypeAdapter

from bench.lifelong import journaled_shift
from gateway.execution.errors import ExecutionError
from gateway.execution.lifelong.executor import LifelongExecutor
from gateway.execution.lifelong.shift_state import HistoryLog, snapshot_shift
from gateway.execution.lifelong.tasks import KEEP, NewTask, TaskError
from gateway.runtime.journal import (
    Journal,
    JournalError,
    JournalRecord,
    RejectedRecord,
    ShiftHistoryRecord,
    ShiftRecord,
    ShiftSnapshotRecord,
    TimeRecord,
)
from gateway.server.runs.shift_journal import JournaledLifelong, replay_shift
from gateway.server.runs.task_journal import TaskJournal
from tests.lifelong.support import small_problem
from tests.lifelong.test_lifelong_executor import drive

_ADAPTER: TypeAdapter[JournalRecord] = TypeAdapter(JournalRecord)
_START = ShiftRecord(run_id="test", wall_start_s=0.0, speed=1.0)
_PROBLEM = small_problem(5, robots=8, size=10, p_delay=0.0)
_NOT_STATE = {"grid", "_record", "sink", "distances", "scheduler", "leg", "pool", "_out",
              "durations", "space"}
"""Attributes that are configuration, outputs or links (the pool is compared on its own)."""


def state(obj: Any) -> Any:
    """Every field of ``obj``, recursively, as plain comparable values."""
    match obj:
        case None | bool() | int() | float() | str():
            return obj
        case enum.Enum():
            return obj.value
        case list() | tuple() | deque() | bytearray():
            return [state(x) for x in obj]
        case set() | frozenset():
            return sorted(state(x) for x in obj)
        case dict():
            return [(k, state(v)) for k, v in obj.items()]
        case _ if dataclasses.is_dataclass(obj) and hasattr(obj, "__slots__"):
            return {f.name: state(getattr(obj, f.name)) for f in dataclasses.fields(obj)}
        case _ if hasattr(obj, "__dict__"):
            return {k: state(v) for k, v in vars(obj).items() if k not in _NOT_STATE}
    raise TypeError(f"no state for {type(obj).__name__}")


def shift_state(ex: LifelongExecutor) -> Any:
    """The executor's state with its task pool's."""
    return {"executor": state(ex), "pool": state(ex.pool)}


class _Shift(JournaledLifelong):
    """Journals its start like the gateway's shift does (the run id is irrelevant here)."""

    def start(self, now_ms: float) -> None:
        if self.sink is not None:
            self.sink(ShiftRecord(run_id="test", wall_start_s=0.0, speed=1.0))
        super().start(now_ms)


def _api(rng: random.Random, rate: float) -> Callable[[LifelongExecutor, float], None]:
    """The task API's and the operator's changes at random moments."""

    def each(ex: LifelongExecutor, t: float) -> None:
        pool = ex.pool
        if rng.random() < rate:
            ids = list(pool.book)
            op = rng.randrange(4)
            with contextlib.suppress(TaskError):  # refused, as the API would answer 409
                if op == 0:
                    free = [c for c in range(ex.grid.size) if ex.grid.free.flat[c]]
                    pool.submit([NewTask((rng.choice(free), rng.choice(free)),
                                         rng.randrange(2)) for _ in range(rng.randint(1, 3))],
                                t, rng.choice([None, f"k{rng.randrange(3)}"]))
                elif ids and op == 1:
                    pool.cancel(rng.choice(ids), t)
                elif ids and op == 2:
                    pool.pause(rng.choice(ids), t)
                elif ids:
                    pool.resume(rng.choice(ids), t)
        assert isinstance(ex, JournaledLifelong)
        if rng.random() < rate / 4:
            if ex.paused:
                ex.resume(t)
            elif rng.random() < 0.5:
                ex.pause(t)
            else:
                # refused while a call is running, or the shift is stopping
                with contextlib.suppress(ExecutionError):
                    ex.plan_now(t)
        elif ex.paused and rng.random() < 0.05:
            ex.resume(t)

    return each


@settings(max_examples=6, deadline=None)
# two keyless submissions at the same time were replayed as one (the backlog's order differed)
@example(seed=2201, lookahead=2, latency=1694.87, turning=False, rate=0.01275, keep=60)
# a checkpoint fell between a refused "replan now" and its ``rejected`` record, which one
# commit always holds together (the engine commits between inputs, never inside one)
@example(seed=284, lookahead=0, latency=918.0, turning=False, rate=0.015625, keep=60)
@given(seed=st.integers(0, 10_000), lookahead=st.integers(0, 2),
       latency=st.floats(0.0, 2000.0), turning=st.booleans(), rate=st.floats(0.0, 0.05),
       keep=st.sampled_from([60, KEEP]))
def test_replaying_the_journal_rebuilds_the_shift_field_by_field(
        seed: int, lookahead: int, latency: float, turning: bool, rate: float,
        keep: int) -> None:
    rng = random.Random(seed)
    history = HistoryLog()
    chunks: list[JournalRecord] = []  # the task history a compacted journal would hold
    with tempfile.TemporaryDirectory() as tmp:
        journal = Journal(Path(tmp) / "journal.sqlite")
        checkpoints: list[tuple[int, Any]] = []
        snapshots: list[tuple[int, list[JournalRecord]]] = []
        made: list[tuple[tuple[Any, ...], dict[str, Any]]] = []
        flush: list[Callable[[], None]] = []

        def executor(*args: Any, **kw: Any) -> LifelongExecutor:
            pool = args[3]  # ``keep`` 60: the pool drops tasks, events and keys as it goes
            pool.keep, pool.events = keep, deque(pool.events, maxlen=keep)
            made.append((copy.deepcopy(args), {**kw, "record": None}))  # a fresh pool too
            ex = _Shift(*args, **kw)
            tasks = TaskJournal(ex.pool, journal)
            flush.append(tasks.flush)

            def sink(rec: JournalRecord) -> None:
                tasks.flush()
                # the state before this input: what is committed (a refusal is no input: it
                # is journaled with the input it refuses, in the same commit)
                if rng.random() < 0.01 and not isinstance(rec, RejectedRecord):
                    journal.commit()
                    checkpoints.append((journal.count(), shift_state(ex)))
                    chunk, drop = history.next(ex.pool)
                    del chunks[:drop]
                    if chunk is not None:
                        chunks.append(_json(ShiftHistoryRecord(history=chunk)))
                    snapshots.append((journal.count(), [*chunks, _json(ShiftSnapshotRecord(
                        shift=_START, speed=1.0, threshold_ms=0.0, replan_marks=[],
                        trace_lines=0, state=snapshot_shift(ex)))]))
                journal.append(rec)

            ex.sink = sink
            return ex

        run = drive(seed, robots=8, size=10, horizon_ms=30_000.0, latency_ms=latency,
                    lookahead=lookahead, turning=turning, threshold_ms=1500.0,
                    executor=executor, each=_api(rng, rate))
        flush[0]()  # the last task events, as the engine's commit does
        journal.commit()
        records = list(journal.records())
        journal.close()
    args, kw = made[0]
    assert len(records) > 100
    end = shift_state(run.ex)

    def replayed(journaled: list[JournalRecord]) -> Any:
        fresh = _Shift(*copy.deepcopy(args), **kw)
        replay_shift(journaled, fresh, on_commands=lambda cs: None,
                     on_report=lambda rec: None, on_start=lambda rec: None)
        return shift_state(fresh)

    for n, want in [*checkpoints, (len(records), end)]:
        _equal(replayed(records[:n]), want, n)
    for (n, compacted), (_, want) in zip(snapshots, checkpoints, strict=True):
        _equal(replayed(compacted), want, ("restored", n))
        _equal(replayed([*compacted, *records[n:]]), end, ("restored and replayed", n))


def _json(rec: JournalRecord) -> JournalRecord:
    """``rec`` written to JSON and read back, as the journal does."""
    return _ADAPTER.validate_json(rec.model_dump_json())


def _equal(got: Any, want: Any, where: Any) -> None:
    """``got`` equals ``want`` in every field of the executor and the pool."""
    for part in ("executor", "pool"):
        for key in want[part]:
            assert got[part][key] == want[part][key], (where, part, key)


def test_a_compacted_journal_stays_bounded_over_a_long_shift_and_resumes_exactly(
        tmp_path: Path) -> None:
    """Two minutes of plan time of eight robots (task API changes and operator pauses
    included), compacted every five segments as the gateway does: the journal never holds
    more than a few seconds' records, while the same shift's uncompacted journal keeps
    growing; replaying the compacted one rebuilds the live shift field by field."""
    compacted, full = Journal(tmp_path / "compacted.sqlite"), Journal(tmp_path / "full.sqlite")
    shift = journaled_shift(_PROBLEM, 5, 120.0, [(compacted, 5), (full, 0)],
                            each=_api(random.Random(5), 0.02))
    records = list(compacted.records())
    written = full.count()
    compacted.close()
    full.close()
    assert shift.live.segments >= 100
    assert len(shift.before_compaction) >= shift.live.segments // 5 - 1  # one per 5 segments
    kinds = [r.kind for r in records]
    chunks = kinds.count("shift_history")  # the task history, a chunk per compaction at most
    assert kinds[:chunks + 1] == ["shift_history"] * chunks + ["shift_snapshot"]
    assert 0 < chunks <= len(shift.before_compaction)
    # bounded: about five seconds of records (~150) whenever it is looked at, against
    # the 3,000+ the uncompacted journal holds at the end
    assert max(shift.before_compaction) * 10 < written
    assert (tmp_path / "compacted.sqlite").stat().st_size * 4 \
        < (tmp_path / "full.sqlite").stat().st_size
    want = shift_state(shift.live)
    fresh = shift.fresh()
    replay_shift(records, fresh, on_commands=lambda cs: None, on_report=lambda rec: None,
                 on_start=lambda rec: None)
    _equal(shift_state(fresh), want, "compacted")


class _KilledAtCommit:
    """A journal's connection whose process is killed when a transaction is to commit."""

    def __init__(self, db: sqlite3.Connection) -> None:
        self.db = db

    def execute(self, sql: str, *args: Any) -> sqlite3.Cursor:
        """Run ``sql``; SIGKILL instead of a ``COMMIT``."""
        if sql == "COMMIT":
            os.kill(os.getpid(), signal.SIGKILL)
        return self.db.execute(sql, *args)

    def executemany(self, sql: str, rows: Any) -> sqlite3.Cursor:
        """Run ``sql`` for each of ``rows``."""
        return self.db.executemany(sql, rows)


def _crash_at_compaction(path: Path, where: str, out: Path) -> None:
    """A child process: a journaled shift killed (SIGKILL) at its third compaction, ``where``
    is ``before`` the snapshot's transaction (its records committed), ``inside`` it (records
    deleted and the snapshot written, not committed) or ``after`` its commit. The snapshot
    it was writing goes to ``out`` first."""
    compact, seen = Journal.compact_shift, []

    def crashing(journal: Journal, snapshot: ShiftSnapshotRecord,
                 history: ShiftHistoryRecord | None, drop: int) -> None:
        seen.append(snapshot)
        if len(seen) < 3:
            compact(journal, snapshot, history, drop)
            return
        out.write_text(snapshot.model_dump_json())
        if where == "inside":
            journal._db = _KilledAtCommit(journal._db)  # type: ignore[assignment]
        if where != "before":
            compact(journal, snapshot, history, drop)
        os.kill(os.getpid(), signal.SIGKILL)

    Journal.compact_shift = crashing  # type: ignore[method-assign]
    journaled_shift(_PROBLEM, 5, 60.0, [(Journal(path), 3)], each=_api(random.Random(5), 0.02))


@pytest.mark.parametrize("where", ["before", "inside", "after"])
def test_a_crash_at_a_compaction_replays_to_the_shift_it_killed(tmp_path: Path,
                                                                 where: str) -> None:
    """SIGKILL right before a compaction's transaction, in the middle of it (the records
    deleted, the snapshot written, no commit) or right after its commit: the journal holds
    the records (the two first cases: the transaction never happened) or the snapshot, and
    both replay to the state the shift had when it was killed."""
    path, out = tmp_path / "journal.sqlite", tmp_path / "snapshot.json"
    child = multiprocessing.get_context("spawn").Process(
        target=_crash_at_compaction, args=(path, where, out))
    child.start()
    child.join(120)
    assert child.exitcode == -signal.SIGKILL
    killed = _ADAPTER.validate_json(out.read_text())
    assert isinstance(killed, ShiftSnapshotRecord)
    journal = Journal(path)
    records = list(journal.records())
    journal.close()
    kinds = [r.kind for r in records]
    # two compactions happened before: the journal holds the task history's chunks, then
    # the second one's snapshot and the records after it, or (after the commit) the chunks
    # and the killed one's snapshot
    chunks = kinds.count("shift_history")
    assert chunks >= 2 and kinds[:chunks] == ["shift_history"] * chunks
    assert kinds[chunks] == "shift_snapshot"
    assert (records[chunks:] == [killed]) == (where == "after")
    assert (len(records) > chunks + 1) == (where != "after")
    configured = journaled_shift(_PROBLEM, 5, 1.0, [(Journal(tmp_path / "j2.sqlite"), 0)])
    fresh = configured.fresh()
    replay_shift(records, fresh, on_commands=lambda cs: None, on_report=lambda rec: None,
                 on_start=lambda rec: None)
    assert snapshot_shift(fresh) == killed.state


def test_a_snapshot_that_does_not_fit_is_a_one_line_journal_error(tmp_path: Path) -> None:
    """A snapshot of another layout version, or of another fleet, stops the replay with a
    precise journal error (the gateway prints it as one line), not a traceback."""
    shift = journaled_shift(_PROBLEM, 5, 3.0, [(Journal(tmp_path / "j.sqlite"), 0)])
    snap = ShiftSnapshotRecord(shift=_START, speed=1.0, threshold_ms=0.0, replan_marks=[],
                               trace_lines=0, state=snapshot_shift(shift.live))
    for state, says in [
            (dataclasses.replace(snap.state, version=99), "of version 99 cannot be restored"),
            (dataclasses.replace(snap.state, robots=9), "of 9 robots, the configuration has 8")]:
        bad = snap.model_copy(update={"state": state})
        with pytest.raises(JournalError, match=says):
            replay_shift([bad], shift.fresh(), on_commands=lambda cs: None,
                         on_report=lambda rec: None, on_start=lambda rec: None)


def test_a_shift_compaction_keeps_the_task_history_chunks_still_needed(tmp_path: Path) -> None:
    """One transaction replaces every record but the task history's chunks by the snapshot,
    drops the oldest chunks the pool no longer needs and writes the new chunk before the
    snapshot; a compaction with nothing new keeps the chunks as they are."""
    shift = journaled_shift(_PROBLEM, 5, 3.0, [(Journal(tmp_path / "j.sqlite"), 0)])
    chunk = HistoryLog().next(shift.live.pool)[0]
    assert chunk is not None
    snap = ShiftSnapshotRecord(shift=_START, speed=1.0, threshold_ms=0.0, replan_marks=[],
                               trace_lines=0, state=snapshot_shift(shift.live))
    first, second = (ShiftHistoryRecord(history=dataclasses.replace(chunk, keys=[(k, [], [])]))
                     for k in ("first", "second"))
    journal = Journal(tmp_path / "journal.sqlite")
    tick = TimeRecord(kind="tick", t_ms=1.0)
    steps: list[tuple[ShiftHistoryRecord | None, int, list[JournalRecord]]] = [
        (first, 0, [first, snap]), (second, 0, [first, second, snap]),
        (None, 1, [second, snap]), (None, 0, [second, snap])]
    for new, drop, want in steps:
        journal.append(tick)
        journal.commit()
        journal.compact_shift(snap, new, drop)
        assert list(journal.records()) == want
    journal.close()
