"""The gateway's journal: what the engine accepted, durable before it takes effect.

An SQLite database in WAL mode with one table of records, written by one writer (the engine's
owner task). The records are the inputs of the current run's executor, in order: the run
itself (its plan and every parameter the executor was built with), every robot report the
executor was given, every monitor tick, pause, resume, replan request, adopted or abandoned
plan, policy change, and every intruder report. Replaying them through a fresh executor
(:func:`gateway.server.runs.resume.replay`) rebuilds it, its monitor included, exactly: the executor
is deterministic and reads no clock.

:meth:`Journal.append` buffers; :meth:`Journal.commit` writes the buffer in one transaction.
The engine commits before its owner task yields to the event loop, so nothing it sent (an
action, a cancel, an acknowledgement) leaves the process before the records that caused it are
in the journal. With ``synchronous=NORMAL`` a commit survives the process being killed
(``kill -9``, an OOM kill); a power cut may lose the last commits, which robots' ``hello``
re-synchronises (a finish the journal missed is caught up exactly once).

Checkpoints stay off the commit path: the writer's connection never checkpoints by itself
(``wal_autocheckpoint=0``: SQLite's automatic checkpoint would copy and ``fsync`` in the middle of
a commit, stalling the engine). A :class:`Checkpointer` thread with its own connection copies the
WAL into the database every ``CHECKPOINT_PERIOD_S`` (``PASSIVE``: it never blocks the writer).
Under continuous writes a passive checkpoint never catches up with the last frames, so the WAL
would never start over and would grow without end: once it holds more than ``wal_bound_pages``
the checkpointer asks the writer to catch up the few frames written since its pass, at its next
commit (``wal_checkpoint(RESTART)`` on the writer's own connection, so no lock is waited for);
the next transaction then writes the WAL from its start, and ``journal_size_limit`` trims the
file.

Size: a new run deletes the records of the previous ones (the journal holds one run), and a new
plan compacts it: :meth:`Journal.compact` replaces every record by one snapshot of what the
executor carries into the plan (:class:`SnapshotRecord`). The file's free pages are returned at
those plan boundaries (``auto_vacuum=INCREMENTAL``).

In lifelong mode the journal holds the shift instead: the task book's changes
(:class:`TaskRecord`), the shift's start (:class:`ShiftRecord`), and the inputs of its executor
(reports, ticks, pause, resume, stop, "plan now", adopted segments (:class:`SegmentRecord`),
failed planner calls), from which a restarted gateway replays the shift
(:mod:`gateway.server.runs.shift_journal`). Every few segments :meth:`Journal.compact` replaces
them by one :class:`ShiftSnapshotRecord` of the shift's state.
"""

from __future__ import annotations

import contextlib
import fcntl
import functools
import hashlib
import json
import math
import os
import secrets
import sqlite3
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Annotated, Literal, get_args

from pydantic import BaseModel, ConfigDict, Field, TypeAdapter, ValidationError

from gateway.execution.lifelong.shift_state import ShiftHistory, ShiftState

Cell = tuple[int, int]


class _Record(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)


class RunRecord(_Record):
    """A run starts (time 0): the plan and everything the executor was built with."""

    kind: Literal["run"] = "run"
    run_id: str
    wall_start_s: float
    """Unix time of the run's time 0 (a restarted gateway continues the run's clock)."""
    speed: float
    map_name: str
    map_text: str
    """The map (MovingAI format): a resumed run does not depend on the map files."""
    paths: list[list[Cell]]
    headings: list[list[int]] | None = None
    policy: str
    policy_seed: int
    threshold_ms: float
    makespan_lb_ms: float
    action_ms: float
    drop_waits: bool
    max_replans: int
    lookahead: int
    durations: list[tuple[float, float, float]]
    """Per robot: t_x of a move, a turn and a wait (ms)."""
    block_history: list[float] = []
    """How long the blocks of the gateway's earlier runs lasted (ms): where the block
    estimates of informed and shadow replanning start from."""


ExecutorEvent = Literal["started", "finished", "blocked", "stopped", "unblocked", "cancelled",
                        "refused"]


class ReportRecord(_Record):
    """A robot report given to the executor (applied, or refused by it: replay does the same)."""

    kind: Literal["report"] = "report"
    event: ExecutorEvent
    robot: int
    plan: int
    index: int
    t_ms: float
    reason: str = ""
    """A refusal's reason (the robot's words)."""


class TimeRecord(_Record):
    """A monitor tick, a pause, a resume, a replan request or an abandoned replan at ``t_ms``
    (in a lifelong shift also its ``stop``; ``replan`` is the operator's "plan now" and
    ``abandon`` a planner call that failed)."""

    kind: Literal["tick", "pause", "resume", "replan", "abandon", "stop"]
    t_ms: float


class AdoptRecord(_Record):
    """The solver's new plan (epoch + 1) adopted at ``t_ms``; ``solver_ms`` were charged."""

    kind: Literal["adopt"] = "adopt"
    t_ms: float
    paths: list[list[Cell]]
    headings: list[list[int]] | None = None
    solver_ms: float


class ShadowRecord(_Record):
    """A shadow solve came back at ``t_ms`` with this plan (None: it found none)."""

    kind: Literal["shadow"] = "shadow"
    t_ms: float
    paths: list[list[Cell]] | None
    headings: list[list[int]] | None = None


class PolicyRecord(_Record):
    """The operator set the replanning policy (``threshold_ms`` set alone: same policy)."""

    kind: Literal["policy"] = "policy"
    policy: str
    policy_seed: int
    threshold_ms: float
    makespan_lb_ms: float
    replace: bool
    """True: a new policy object (set_policy); False: only the slack threshold changed."""


class IntruderRecord(_Record):
    """A world reported an intruder on (or off) ``cell`` at ``t_ms``."""

    kind: Literal["intruder"] = "intruder"
    t_ms: float
    cell: Cell
    state: Literal["on", "off"]


class SpeedRecord(_Record):
    """The operator changed the clock's speed."""

    kind: Literal["speed"] = "speed"
    speed: float


class TaskRecord(_Record):
    """A change of a task of a lifelong shift (an event of the task book, in order; its
    ``seq`` is the event's). A ``queued`` record also carries what the task is (``errands``
    as flat cell ids, priority, deadline, idempotency key, whether the task list made it), so
    a restart can rebuild the book from the records alone."""

    kind: Literal["task"] = "task"
    seq: int
    task: int
    state: Literal["queued", "paused", "assigned", "started", "finished", "cancelled"]
    robot: int
    done: int
    t_ms: float
    errands: list[int] | None = None
    priority: int = 0
    deadline_ms: float | None = None
    key: str | None = None
    listed: bool = False
    batch: int | None = None
    """On a submitted task's ``queued`` records: the id of the first task of its submission
    (journals written before it had none; a run of new tasks with the same time and key then
    counts as one submission)."""


class ShiftRecord(_Record):
    """A lifelong shift starts (plan time 0): its run id (the first part of its action ids)
    and the wall time and clock speed of its time 0 (a restarted gateway continues the
    shift's clock). The shift's parameters are the configuration's."""

    kind: Literal["shift"] = "shift"
    run_id: str
    wall_start_s: float
    speed: float


class SegmentRecord(_Record):
    """The planner's window for call ``call`` adopted at ``t_ms`` by a lifelong shift
    (the :class:`~gateway.execution.lifelong.executor.Segment`: planner states step by step, the
    steps at which each robot reaches its goals, and PIBT's priorities after it)."""

    kind: Literal["segment"] = "segment"
    call: int
    t_ms: float
    states: list[list[int]]
    reached: list[list[int]]
    priorities: list[int] = []
    """PIBT's priorities at the window's end (empty in a journal written before they were
    kept)."""


class ThresholdRecord(_Record):
    """The operator set a lifelong shift's slack threshold."""

    kind: Literal["threshold"] = "threshold"
    threshold_ms: float


class RejectedRecord(_Record):
    """The executor refused the input journaled just before (an ``ExecutionError``: nothing
    changed, e.g. a robot's late or out-of-order report). Replay must refuse that input too, and
    accept every input not followed by one: anything else is a journal that does not replay
    what happened (damage), never a silently different state."""

    kind: Literal["rejected"] = "rejected"


REJECTED = RejectedRecord()


class SnapshotRecord(_Record):
    """A plan boundary: the run's records up to plan ``plan_id`` adopted at ``t_ms``, compacted.
    It holds what the executor carries into a new plan (the rest of its state starts afresh
    with the plan) and what the engine keeps besides; replaying it gives what replaying those
    records gave."""

    kind: Literal["snapshot"] = "snapshot"
    run: RunRecord
    """The run (its parameters, map and first plan)."""
    plan_id: int
    t_ms: float
    paths: list[list[Cell]]
    headings: list[list[int]] | None = None
    solver_ms: float
    completions_ms: list[float]
    """Per robot: when its latest action finished."""
    replans: int
    paused: bool
    blocks_open: list[tuple[Cell, float, float]]
    """Open blocks: cell, since, last seen."""
    blocks_history: list[float]
    """Durations of the blocks that cleared."""
    policy: str
    policy_seed: int
    threshold_ms: float
    policy_state: dict[str, float | bool | None]
    """The policy object's attributes (e.g. a random replan's time and whether it fired)."""
    speed: float
    intruders: list[Cell]
    replan_marks: list[dict[str, float | int | str]]
    """The run's replans so far, as operators see them."""
    trace_lines: int
    """Trace records the run wrote before this plan (its trace file starts with them)."""


class ShiftHistoryRecord(_Record):
    """A chunk of a lifelong shift's task history (ended tasks, events, idempotency keys new
    since the previous chunk: :class:`~gateway.execution.lifelong.shift_state.ShiftHistory`). A
    compaction keeps the chunks the task book may still need, before its snapshot."""

    kind: Literal["shift_history"] = "shift_history"
    history: ShiftHistory


class ShiftSnapshotRecord(_Record):
    """A lifelong shift's records so far, compacted: the shift's start, what its executor and
    task book are (:class:`~gateway.execution.lifelong.shift_state.ShiftState`) and what the engine
    keeps besides; replaying it gives what replaying those records gave."""

    kind: Literal["shift_snapshot"] = "shift_snapshot"
    shift: ShiftRecord
    speed: float
    """The clock's speed."""
    threshold_ms: float
    """The slack threshold operators are shown."""
    replan_marks: list[dict[str, float | int | str]]
    """The shift's planning triggers so far, as operators see them."""
    trace_lines: int
    """Trace records the shift wrote before the snapshot (its trace file starts with them)."""
    state: ShiftState


JournalRecord = Annotated[
    RunRecord | ReportRecord | TimeRecord | AdoptRecord | PolicyRecord | IntruderRecord
    | SpeedRecord | SnapshotRecord | ShadowRecord | TaskRecord | ShiftRecord | SegmentRecord
    | ThresholdRecord | ShiftSnapshotRecord | ShiftHistoryRecord | RejectedRecord,
    Field(discriminator="kind")]
_ADAPTER: TypeAdapter[JournalRecord] = TypeAdapter(JournalRecord)


_EVENTS = frozenset(get_args(ExecutorEvent))
_EMPTY = '""'  # the JSON of an empty reason (every report but a refusal)
_TIME_KINDS = frozenset(get_args(TimeRecord.model_fields["kind"].annotation))


def _finite(x: object) -> bool:
    return type(x) is float and math.isfinite(x)


def plain(record: _Record) -> bool:
    """Whether ``record`` is a report or a time record (the kinds written for every action and
    tick) whose values round-trip by construction: a valid kind and event, exact ints, finite
    floats, ASCII text. Its model would read its JSON back as an equal record, so
    :meth:`Journal.encode` skips the read-back; any other record is read back."""
    d = record.__dict__
    if type(record) is ReportRecord:
        reason = d["reason"]
        return (d["event"] in _EVENTS and type(d["robot"]) is int and type(d["plan"]) is int
                and type(d["index"]) is int and _finite(d["t_ms"]) and type(reason) is str
                and reason.isascii())
    return type(record) is TimeRecord and d["kind"] in _TIME_KINDS and _finite(d["t_ms"])


class EncodedReport:
    """A :class:`ReportRecord` already encoded, as :func:`report_json` writes it (the owner's
    hot path: one per robot report, no model built); :meth:`Journal.append` writes its body
    as it is."""

    __slots__ = ("body",)
    kind = "report"

    def __init__(self, body: str) -> None:
        self.body = body


def report_json(event: str, robot: int, plan: int, index: int, t_ms: float,
                reason: str = "") -> str | None:
    """The JSON of the report record of these values if they round-trip by construction (as
    :func:`plain` checks a record's: a valid event, exact ints, a finite float, ASCII text),
    written directly; None otherwise (the caller builds the record: it is read back)."""
    if not (event in _EVENTS and type(robot) is int and type(plan) is int
            and type(index) is int and _finite(t_ms) and type(reason) is str
            and reason.isascii()):
        return None
    why = json.dumps(reason) if reason else _EMPTY
    return (f'{{"kind":"report","event":"{event}","robot":{robot},"plan":{plan},'
            f'"index":{index},"t_ms":{t_ms!r},"reason":{why}}}')


class JournalError(Exception):
    """The journal cannot be opened or read; the message says why."""


class JournalWriteError(JournalError):
    """A write or sync of the journal failed: nothing of the failed transaction is on disk, and
    the journal takes no more writes (what was acknowledged before stays; a retry could not be
    trusted, as PostgreSQL's PANIC on an ``fsync`` failure)."""


DURABLE_KINDS = frozenset({"run", "task", "shift", "policy", "threshold", "speed", "pause",
                           "resume", "replan", "stop", "abandon", "adopt", "segment",
                           "intruder", "shadow"})
"""Record kinds committed with ``synchronous=FULL`` (the WAL is synced before the commit
returns): what a WMS, an operator or a robot is told was accepted and cannot re-send, and what
robots are given actions from. A transaction with any of them syncs the records before it too.
Reports and ticks are committed with ``NORMAL`` (a power cut may lose the last of them: the
robots' ``hello`` carries what they reported again)."""

_CREATE_RECORDS = ("CREATE TABLE records (seq INTEGER PRIMARY KEY, kind TEXT NOT NULL, "
                   "body TEXT NOT NULL, chain TEXT NOT NULL)")

SEAL_BYTES = 512
"""The seal's size: one sector, written in place (``<journal>.seal``)."""

GENESIS = ""
"""The chain value before a journal's first record."""


def chain_next(prev: str, kind: str, body: str) -> str:
    """The hash chain's value after a record: SHA-256 over the previous value, the record's
    kind and its JSON (the first 32 hex digits). Replay recomputes it: an edited, reordered or
    deleted record (but the last ones: a lost tail) breaks the chain."""
    return hashlib.sha256(f"{prev}\0{kind}\0{body}".encode()).hexdigest()[:32]


ROWS_PER_INSERT = 256
"""Rows a commit of reports and ticks writes with one multi-row ``INSERT`` (768 values, below
the 999 an SQLite may allow); a bigger one is a transaction of several."""


@functools.cache
def _insert_rows(n: int) -> str:
    """The ``INSERT`` of ``n`` records (kind, body, chain)."""
    return "INSERT INTO records (kind, body, chain) VALUES " + ", ".join(["(?, ?, ?)"] * n)


class JournalLock:
    """One writer per journal: an exclusive ``flock`` on ``<journal>.lock`` naming the holder's
    pid. The kernel releases it with its holder's last file descriptor, so a ``kill -9``
    never leaves a stale lock; a second gateway gets a one-line :class:`JournalError`."""

    def __init__(self, journal: Path) -> None:
        self.path = journal.with_name(journal.name + ".lock")
        try:
            journal.parent.mkdir(parents=True, exist_ok=True)
            fd = os.open(self.path, os.O_RDWR | os.O_CREAT, 0o600)
        except OSError as exc:
            raise JournalError(f"cannot open the journal's lock {self.path}: "
                               f"{exc.strerror}") from None
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            holder = os.pread(fd, 32, 0).decode(errors="replace").strip() or "unknown"
            os.close(fd)
            raise JournalError(f"the journal {journal} is in use by process {holder} "
                               f"(one gateway per journal)") from None
        os.ftruncate(fd, 0)
        os.pwrite(fd, f"{os.getpid()}\n".encode(), 0)
        self._fd: int | None = fd

    def release(self) -> None:
        """Give the lock up (closing the descriptor)."""
        if self._fd is not None:
            os.close(self._fd)
            self._fd = None


def new_run_id() -> str:
    """A run id that does not repeat (8 random lower-case hex digits)."""
    return secrets.token_hex(4)


CHECKPOINT_PERIOD_S = 1.0
"""How often the checkpointer copies the WAL into the database."""
WAL_BOUND_PAGES = 8192
"""WAL pages (32 MiB at SQLite's default 4 KiB page) beyond which the WAL is made to start
over (see the module doc)."""


class Checkpointer:
    """A thread that checkpoints the journal at ``path`` every ``period_s`` (PASSIVE, on its own
    connection), and raises :attr:`restart_due` when the WAL outgrew ``bound_pages`` frames."""

    def __init__(self, path: Path, period_s: float, bound_pages: int) -> None:
        self.path = path
        self.period_s = period_s
        self.bound_pages = bound_pages
        self.restart_due = False
        """Set here, cleared by the writer once it caught up the WAL's last frames."""
        self.passes = 0
        self.max_wal_pages = 0
        """The largest WAL seen at a pass (frames)."""
        self.error: str | None = None
        """Why the checkpointer stopped, if it failed (the writer's commits still work)."""
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="journal-checkpoint",
                                        daemon=True)
        self._thread.start()

    def _run(self) -> None:
        try:
            db = sqlite3.connect(self.path, isolation_level=None)
        except sqlite3.Error as exc:
            self.error = str(exc)
            return
        try:
            while not self._stop.wait(self.period_s):
                self.checkpoint(db)
        except sqlite3.Error as exc:
            self.error = str(exc)
        finally:
            db.close()

    def checkpoint(self, db: sqlite3.Connection) -> None:
        """One passive pass: copy what the WAL holds into the database (never waits)."""
        _busy, frames, _copied = db.execute("PRAGMA wal_checkpoint(PASSIVE)").fetchone()
        self.passes += 1
        self.max_wal_pages = max(self.max_wal_pages, frames)
        if frames > self.bound_pages:
            self.restart_due = True

    def stop(self) -> None:
        """End the thread (after its current pass)."""
        self._stop.set()
        self._thread.join()


class Journal:
    """The SQLite journal at ``path`` (created with its directory if missing). Its first
    write starts a :class:`Checkpointer` (a journal only read never does).

    Every row carries the hash chain's value after it (:func:`chain_next`), checked by
    :meth:`records`; every record is read back before it is buffered (it must round-trip:
    finite numbers only); a failed commit is rolled back, keeps its records buffered and
    makes the journal refuse every later write (:class:`JournalWriteError`)."""

    def __init__(self, path: Path, *, checkpoint_period_s: float = CHECKPOINT_PERIOD_S,
                 wal_bound_pages: int = WAL_BOUND_PAGES) -> None:
        self.path = path
        self._period_s = checkpoint_period_s
        self._bound_pages = wal_bound_pages
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            self._db = sqlite3.connect(path, isolation_level=None, check_same_thread=False)
            self._db.execute("PRAGMA auto_vacuum=INCREMENTAL")
            mode = self._db.execute("PRAGMA journal_mode=WAL").fetchone()[0]
            self._db.execute("PRAGMA synchronous=NORMAL")
            self._db.execute("PRAGMA wal_autocheckpoint=0")  # the checkpointer's job
            page = int(self._db.execute("PRAGMA page_size").fetchone()[0])
            self._db.execute(f"PRAGMA journal_size_limit={wal_bound_pages * page}")
            self._db.execute(_CREATE_RECORDS.replace("TABLE", "TABLE IF NOT EXISTS"))
            self._db.execute("CREATE TABLE IF NOT EXISTS meta ("
                             "key TEXT PRIMARY KEY, value TEXT NOT NULL)")
            columns = [row[1] for row in self._db.execute("PRAGMA table_info(records)")]
            last = self._db.execute(
                "SELECT chain FROM records ORDER BY seq DESC LIMIT 1").fetchone() \
                if "chain" in columns else None
            count = int(self._db.execute("SELECT COUNT(*) FROM records").fetchone()[0])
        except (OSError, sqlite3.Error) as exc:
            raise JournalError(f"cannot open the journal {path}: {exc}") from None
        if mode != "wal":
            raise JournalError(f"the journal {path} cannot use WAL mode (got {mode})")
        self._legacy = "chain" not in columns
        """Written by a fleetgate without checksums: read as damaged, replaced by a new run."""
        self._chain = GENESIS if last is None else str(last[0])
        self._count = count  # records in the table
        self._seal_path = path.with_name(path.name + ".seal")
        self._buffer: list[tuple[str, str]] = []
        self._durable = False  # the buffer holds a kind of DURABLE_KINDS
        self.failed: str | None = None
        """Why a write failed (then every later write is refused)."""
        self.on_failure: Callable[[str], None] | None = None
        """Told (with a one-line message) when a write or sync fails, before the error is
        raised: the gateway ends the process there (:func:`gateway.runtime.exits.fatal`)."""
        self.checkpointer: Checkpointer | None = None
        self.appended = 0
        """Records written since the journal was opened."""
        self.commits = 0
        self.synced_commits = 0
        """Commits made with ``synchronous=FULL`` (:data:`DURABLE_KINDS`)."""
        self.commit_max_ms = 0.0
        """The longest commit (wall time), a checkpoint catch-up included."""
        self.restarts = 0
        """Times the writer caught up the WAL so that it starts over."""

    @staticmethod
    def encode(record: _Record) -> str:
        """``record``'s JSON, read back first: a record that does not round-trip (a number
        that is not finite, a value its model refuses) is refused with a :class:`ValueError`
        before it can reach the journal. A report or a tick of plain values (:func:`plain`)
        round-trips by construction and is not read back (the owner's hot path)."""
        body = record.model_dump_json()
        if plain(record):
            return body
        try:
            again = _ADAPTER.validate_json(body)
        except ValidationError as exc:
            raise ValueError(f"a {record.kind} record does not round-trip: "  # type: ignore[attr-defined]
                             f"{exc.errors(include_url=False)[0]['msg']}") from None
        if again != record:
            raise ValueError(f"a {record.kind} record does not round-trip")  # type: ignore[attr-defined]
        return body

    def append(self, record: _Record | EncodedReport) -> None:
        """Buffer one record (written by the next :meth:`commit`)."""
        if type(record) is EncodedReport:
            self._buffer.append(("report", record.body))
            return
        kind: str = record.kind  # type: ignore[union-attr]
        self._buffer.append((kind, self.encode(record)))  # type: ignore[arg-type]
        if kind in DURABLE_KINDS:
            self._durable = True

    def _fail(self, what: str, exc: Exception) -> JournalWriteError:
        """A write failed: the journal takes no more; :attr:`on_failure` is told first."""
        self.failed = str(exc)
        message = f"{what} {self.path}: {exc}"
        if self.on_failure is not None:
            self.on_failure(message)
        return JournalWriteError(message)

    def _check_writable(self) -> None:
        if self.failed is not None:
            raise JournalWriteError(f"the journal {self.path} failed earlier: {self.failed}")

    def _write(self, statements: list[tuple[str, tuple[object, ...]]],
               rows: list[tuple[str, str]], chain: str, *, full: bool,
               replace: bool = False) -> None:
        """One transaction: ``statements``, then ``rows`` chained from ``chain`` (after every
        record, or instead of them if ``replace``); on any error it is rolled back and the
        journal fails (:class:`JournalWriteError`). A synced one is sealed after it (and a
        ``replace`` before it too: either side of its commit is then a sealed state)."""
        self._check_writable()
        db = self._db
        chained = []
        for kind, body in rows:
            chain = chain_next(chain, kind, body)
            chained.append((kind, body, chain))
        count = len(rows) if replace else self._count + len(rows)
        if replace:
            self._seal([(self._count, self._chain), (count, chain)])
        try:
            if not (full or statements or len(chained) > ROWS_PER_INSERT):
                # a report or tick commit (the owner's hot path): one statement, which SQLite
                # makes a transaction of its own (autocommit), not BEGIN + insert + COMMIT
                db.execute(_insert_rows(len(chained)), [v for row in chained for v in row])
            else:
                self._transaction(db, statements, chained, full)
        except sqlite3.Error as exc:
            with contextlib.suppress(sqlite3.Error):
                db.execute("ROLLBACK")
            raise self._fail("cannot write the journal", exc) from None
        self._chain, self._count = chain, count
        self.appended += len(rows)
        self.synced_commits += full
        if full:
            self._seal([(count, chain)])

    @staticmethod
    def _transaction(db: sqlite3.Connection, statements: list[tuple[str, tuple[object, ...]]],
                     chained: list[tuple[str, str, str]], full: bool) -> None:
        """``statements``, then the ``chained`` rows, in one transaction (synced if
        ``full``)."""
        if full:
            db.execute("PRAGMA synchronous=FULL")
        db.execute("BEGIN")
        for sql, args in statements:
            db.execute(sql, args)
        db.executemany(_insert_rows(1), chained)
        db.execute("COMMIT")
        if full:
            db.execute("PRAGMA synchronous=NORMAL")

    def _seal(self, states: list[tuple[int, str]]) -> None:
        """Write and sync the seal: the journal holds (at least) one of ``states`` (record
        count, chain value after the last of them) once the commit being made returned."""
        body = json.dumps(states).encode().ljust(SEAL_BYTES)
        try:
            fd = os.open(self._seal_path, os.O_WRONLY | os.O_CREAT, 0o600)
            try:
                os.pwrite(fd, body, 0)
                os.fdatasync(fd)
            finally:
                os.close(fd)
        except OSError as exc:
            raise self._fail("cannot seal the journal", exc) from None

    def synced(self) -> int:
        """How many records (the first ones) the last synced commit made durable, as its seal
        says (0: none): a power cut can only lose the records after them."""
        try:
            raw = self._seal_path.read_bytes()
            return max((int(n) for n, _ in json.loads(raw.rstrip(b" ") or b"[]")), default=0)
        except (OSError, ValueError, TypeError):
            return 0

    def check_sealed(self) -> None:
        """The journal holds a state its seal names (:class:`JournalError` if not: synced
        records were lost, e.g. with a damaged or deleted WAL). Checked before anything is
        written (a new seal would hide the loss) and by :meth:`records`."""
        try:
            raw = self._seal_path.read_bytes()
        except FileNotFoundError:
            return  # never sealed (a copy of a journal, or one never synced)
        except OSError as exc:
            raise JournalError(f"cannot read the seal of the journal {self.path}: "
                               f"{exc.strerror}") from None
        try:
            states = [(int(n), str(c)) for n, c in json.loads(raw.rstrip(b" ") or b"[]")]
        except (ValueError, TypeError):
            raise JournalError(f"the seal of the journal {self.path} is damaged: start with "
                               f"--fresh to abandon the run") from None
        for n, chain in states:
            row = self._db.execute("SELECT chain FROM records ORDER BY seq LIMIT 1 OFFSET ?",
                                   (n - 1,)).fetchone() if n else (GENESIS,)
            if row is not None and row[0] == chain:
                return
        if states:
            raise JournalError(f"the journal {self.path} lost synced records "
                               f"({max(n for n, _ in states)} were committed and synced, "
                               f"{self._count} are there: its WAL was damaged or deleted): "
                               f"start with --fresh to abandon the run")

    def commit(self) -> bool:
        """Write the buffered records in one transaction (synced if one of them is of
        :data:`DURABLE_KINDS`); False if there were none. On failure they stay buffered and
        nothing of them is written."""
        if not self._buffer:
            return False
        t0 = time.perf_counter()
        self._write([], self._buffer, self._chain, full=self._durable)
        self._buffer, self._durable = [], False
        self._after_write(t0)
        return True

    def _after_write(self, t0: float) -> None:
        """Start the checkpointer on the first write; catch up the WAL if it asked."""
        cp = self.checkpointer
        if cp is None:
            self.checkpointer = Checkpointer(self.path, self._period_s, self._bound_pages)
        elif cp.error is not None:  # a checkpoint could not copy or sync: nothing is safe
            raise self._fail("cannot checkpoint the journal", sqlite3.Error(cp.error))
        elif cp.restart_due:
            # the frames since the checkpointer's last pass: few, and nobody waits for a lock
            try:
                busy = self._db.execute("PRAGMA wal_checkpoint(RESTART)").fetchone()[0]
            except sqlite3.Error as exc:
                raise self._fail("cannot checkpoint the journal", exc) from None
            if not busy:  # else the checkpointer was in a pass: ask again after the next
                cp.restart_due = False
                self.restarts += 1
        self.commits += 1
        self.commit_max_ms = max(self.commit_max_ms, (time.perf_counter() - t0) * 1000.0)

    def _replace(self, *records: _Record, keep: str = "", drop: int = 0) -> None:
        """Forget every record but those of kind ``keep`` (less the ``drop`` oldest of
        them) and write ``records`` after them (one synced transaction: the kept rows are
        chained again from the start), then return the free pages (a plan boundary: nobody
        waits for the fleet meanwhile)."""
        t0 = time.perf_counter()
        self._check_writable()
        rows = [(r.kind, self.encode(r)) for r in records]  # type: ignore[attr-defined]
        try:
            kept = [(k, b) for k, b in self._db.execute(
                "SELECT kind, body FROM records WHERE kind = ? ORDER BY seq", (keep,))][drop:]
        except sqlite3.Error as exc:
            raise self._fail("cannot read the journal", exc) from None
        self._buffer, self._durable = [], False
        self._write([("DELETE FROM records", ())], kept + rows, GENESIS, full=True,
                    replace=True)
        self.appended -= len(kept)
        with contextlib.suppress(sqlite3.Error):  # returning free pages is an optimisation
            self._db.execute("PRAGMA incremental_vacuum")
        self._after_write(t0)

    def begin_run(self, run: RunRecord) -> None:
        """A new run: forget every earlier record (the plan boundary) and write ``run``."""
        self._replace(run)

    def compact(self, snapshot: _Record) -> None:
        """``snapshot`` (a :class:`SnapshotRecord` at a new plan) sums up every record so far
        and replaces them."""
        self._replace(snapshot)

    def compact_shift(self, snapshot: ShiftSnapshotRecord, history: ShiftHistoryRecord | None,
                      drop: int) -> None:
        """A shift's ``snapshot`` sums up every record so far and replaces them, except the
        chunks of its task history (:class:`ShiftHistoryRecord`), less the ``drop`` oldest;
        the new chunk ``history`` (if any) is written before the snapshot."""
        records = (snapshot,) if history is None else (history, snapshot)
        self._replace(*records, keep="shift_history", drop=drop)

    def discard(self) -> None:
        """Forget the journaled run and its configuration (starting fresh on purpose); a
        journal of an earlier format is made anew. Synced before it returns."""
        fresh = [("DROP TABLE records", ()), (_CREATE_RECORDS, ())] if self._legacy \
            else [("DELETE FROM records", ())]
        self._write([*fresh, ("DELETE FROM meta", ())], [], GENESIS, full=True, replace=True)
        self._legacy = False
        self._buffer, self._durable = [], False
        with contextlib.suppress(sqlite3.Error):
            self._db.execute("PRAGMA incremental_vacuum")

    @property
    def legacy(self) -> bool:
        """Written by a fleetgate without checksums (its records are refused; ``--fresh``
        makes it anew)."""
        return self._legacy

    def fingerprint(self) -> dict[str, str] | None:
        """The configuration the journaled run was started with (None: none was recorded)."""
        try:
            row = self._db.execute("SELECT value FROM meta WHERE key = 'config'").fetchone()
            if row is None:
                return None
            value = json.loads(row[0])
        except sqlite3.Error as exc:
            raise JournalError(f"cannot read the journal {self.path}: {exc}") from None
        except ValueError:
            raise JournalError(f"the journal {self.path}'s configuration fingerprint is "
                               f"damaged") from None
        return {str(k): str(v) for k, v in value.items()}

    def set_fingerprint(self, fields: dict[str, str]) -> None:
        """Record the configuration the journal's runs are made with (synced)."""
        self._write([("INSERT OR REPLACE INTO meta (key, value) VALUES ('config', ?)",
                      (json.dumps(fields, sort_keys=True),))], [], self._chain, full=True)

    def records(self) -> Iterator[JournalRecord]:
        """The journaled run's records in order (none if there is no run), each checked against
        the hash chain and its model: a damaged journal is a :class:`JournalError` naming the
        first bad record."""
        if self._legacy:
            raise JournalError(f"the journal {self.path} was written by an earlier fleetgate "
                               f"(records without checksums): start with --fresh to abandon "
                               f"its run")
        try:
            rows = self._db.execute(
                "SELECT kind, body, chain FROM records ORDER BY seq").fetchall()
        except sqlite3.Error as exc:
            raise JournalError(f"cannot read the journal {self.path}: {exc}") from None
        chain = GENESIS
        for seq, (kind, body, stored) in enumerate(rows, 1):
            chain = chain_next(chain, kind, body)
            if chain != stored:
                raise JournalError(f"record {seq} of the journal {self.path} is damaged "
                                   f"(its checksum does not match): start with --fresh to "
                                   f"abandon the run")
        self.check_sealed()
        for seq, (kind, body, _) in enumerate(rows, 1):
            try:
                rec = _ADAPTER.validate_json(body)
            except ValidationError as exc:
                raise JournalError(f"record {seq} of the journal {self.path} is not valid: "
                                   f"{exc.errors(include_url=False)[0]['msg']}") from None
            if rec.kind != kind:
                raise JournalError(f"record {seq} of the journal {self.path} is not valid: "
                                   f"kind {kind} holds a {rec.kind} record")
            yield rec

    def count(self) -> int:
        """How many records are committed."""
        return int(self._db.execute("SELECT COUNT(*) FROM records").fetchone()[0])

    def wal_bytes(self) -> int:
        """The WAL file's size (0 if there is none)."""
        wal = self.path.with_name(self.path.name + "-wal")
        return wal.stat().st_size if wal.exists() else 0

    def close(self) -> None:
        """Commit what is buffered (unless the journal failed), stop the checkpointer and
        close the database."""
        try:
            if self.failed is None:
                self.commit()
        finally:
            if self.checkpointer is not None:
                self.checkpointer.stop()
                self.checkpointer = None
            self._db.close()
