"""Replaying a lifelong shift's journal rebuilds it field by field: a shift driven in virtual
time (robots with jittered durations and stops, planner answers after a random latency, task
API changes and operator pauses at random moments) journals its inputs into a real SQLite
journal; at random points and at the end, a fresh executor fed the committed records must equal
the live one in every field (executor, live ADG, errand book, task pool)."""

from __future__ import annotations

import contextlib
import copy
import dataclasses
import enum
import random
import tempfile
from collections import deque
from collections.abc import Callable
from pathlib import Path
from typing import Any

from hypothesis import given, settings
from hypothesis import strategies as st

from gateway.execution.errors import ExecutionError
from gateway.execution.lifelong import LifelongExecutor
from gateway.execution.tasks import NewTask, TaskError
from gateway.runtime.journal import Journal, JournalRecord, ShiftRecord
from gateway.server.shift_journal import JournaledLifelong, replay_shift
from gateway.server.task_journal import TaskJournal
from tests.lifelong.test_lifelong_executor import drive

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
@given(seed=st.integers(0, 10_000), lookahead=st.integers(0, 2),
       latency=st.floats(0.0, 2000.0), turning=st.booleans(), rate=st.floats(0.0, 0.05))
def test_replaying_the_journal_rebuilds_the_shift_field_by_field(
        seed: int, lookahead: int, latency: float, turning: bool, rate: float) -> None:
    rng = random.Random(seed)
    with tempfile.TemporaryDirectory() as tmp:
        journal = Journal(Path(tmp) / "journal.sqlite")
        checkpoints: list[tuple[int, Any]] = []
        made: list[tuple[tuple[Any, ...], dict[str, Any]]] = []
        flush: list[Callable[[], None]] = []

        def executor(*args: Any, **kw: Any) -> LifelongExecutor:
            made.append((copy.deepcopy(args), {**kw, "record": None}))  # a fresh pool too
            ex = _Shift(*args, **kw)
            tasks = TaskJournal(ex.pool, journal)
            flush.append(tasks.flush)

            def sink(rec: JournalRecord) -> None:
                tasks.flush()
                if rng.random() < 0.01:  # the state before this input: what is committed
                    journal.commit()
                    checkpoints.append((journal.count(), shift_state(ex)))
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
    for n, want in [*checkpoints, (len(records), shift_state(run.ex))]:
        fresh = _Shift(*copy.deepcopy(args), **kw)
        replay_shift(records[:n], fresh, on_commands=lambda cs: None,
                     on_report=lambda rec: None, on_start=lambda rec: None)
        got = shift_state(fresh)
        for part in ("executor", "pool"):
            for key in want[part]:
                assert got[part][key] == want[part][key], (n, part, key)
