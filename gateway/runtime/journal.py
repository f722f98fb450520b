"""The gateway's journal: what the engine accepted, durable before it takes effect.

An SQLite database in WAL mode with one table of records, written by one writer (the engine's
owner task). The records are the inputs of the current run's executor, in order: the run
itself (its plan and every parameter the executor was built with), every robot report the
executor was given, every monitor tick, pause, resume, replan request, adopted or abandoned
plan, policy change, and every intruder report. Replaying them through a fresh executor
(:func:`gateway.server.resume.replay`) rebuilds it, its monitor included, exactly: the executor
is deterministic and reads no clock.

:meth:`Journal.append` buffers; :meth:`Journal.commit` writes the buffer in one transaction.
The engine commits before its owner task yields to the event loop, so nothing it sent (an
action, a cancel, an acknowledgement) leaves the process before the records that caused it are
in the journal. With ``synchronous=NORMAL`` a commit survives the process being killed
(``kill -9``, an OOM kill); a power cut may lose the last commits, which robots' ``hello``
re-synchronises (a finish the journal missed is caught up exactly once).

In lifelong mode the journal holds the task book's changes instead (:class:`TaskRecord`), from
which a restarted gateway rebuilds it (:mod:`gateway.server.task_journal`).

Size: a new run deletes the records of the previous ones (the journal holds one run), and the
file's free pages are returned at that plan boundary (``auto_vacuum=INCREMENTAL``).
"""

from __future__ import annotations

import secrets
import sqlite3
from collections.abc import Iterator
from pathlib import Path
from typing import Annotated, Literal

from pydantic import BaseModel, ConfigDict, Field, TypeAdapter, ValidationError

Cell = tuple[int, int]


class _Record(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


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
    """A monitor tick, a pause, a resume, a replan request or an abandoned replan at ``t_ms``."""

    kind: Literal["tick", "pause", "resume", "replan", "abandon"]
    t_ms: float


class AdoptRecord(_Record):
    """The solver's new plan (epoch + 1) adopted at ``t_ms``; ``solver_ms`` were charged."""

    kind: Literal["adopt"] = "adopt"
    t_ms: float
    paths: list[list[Cell]]
    headings: list[list[int]] | None = None
    solver_ms: float


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


JournalRecord = Annotated[
    RunRecord | ReportRecord | TimeRecord | AdoptRecord | PolicyRecord | IntruderRecord
    | SpeedRecord | TaskRecord,
    Field(discriminator="kind")]
_ADAPTER: TypeAdapter[JournalRecord] = TypeAdapter(JournalRecord)


class JournalError(Exception):
    """The journal cannot be opened or read; the message says why."""


def new_run_id() -> str:
    """A run id that does not repeat (8 random lower-case hex digits)."""
    return secrets.token_hex(4)


class Journal:
    """The SQLite journal at ``path`` (created with its directory if missing)."""

    def __init__(self, path: Path) -> None:
        self.path = path
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            self._db = sqlite3.connect(path, isolation_level=None, check_same_thread=False)
            self._db.execute("PRAGMA auto_vacuum=INCREMENTAL")
            mode = self._db.execute("PRAGMA journal_mode=WAL").fetchone()[0]
            self._db.execute("PRAGMA synchronous=NORMAL")
            self._db.execute("CREATE TABLE IF NOT EXISTS records ("
                             "seq INTEGER PRIMARY KEY, kind TEXT NOT NULL, body TEXT NOT NULL)")
        except (OSError, sqlite3.Error) as exc:
            raise JournalError(f"cannot open the journal {path}: {exc}") from None
        if mode != "wal":
            raise JournalError(f"the journal {path} cannot use WAL mode (got {mode})")
        self._buffer: list[tuple[str, str]] = []
        self.appended = 0
        """Records written since the journal was opened."""

    def append(self, record: _Record) -> None:
        """Buffer one record (written by the next :meth:`commit`)."""
        self._buffer.append((record.kind, record.model_dump_json()))  # type: ignore[attr-defined]

    def commit(self) -> None:
        """Write the buffered records in one transaction."""
        if not self._buffer:
            return
        rows, self._buffer = self._buffer, []
        db = self._db
        db.execute("BEGIN")
        db.executemany("INSERT INTO records (kind, body) VALUES (?, ?)", rows)
        db.execute("COMMIT")
        self.appended += len(rows)

    def begin_run(self, run: RunRecord) -> None:
        """A new run: forget every earlier record (the plan boundary) and write ``run``."""
        self._buffer.clear()
        db = self._db
        db.execute("BEGIN")
        db.execute("DELETE FROM records")
        db.execute("INSERT INTO records (kind, body) VALUES (?, ?)",
                   (run.kind, run.model_dump_json()))
        db.execute("COMMIT")
        db.execute("PRAGMA incremental_vacuum")
        db.execute("PRAGMA wal_checkpoint(TRUNCATE)")

    def discard(self) -> None:
        """Forget the journaled run (starting fresh on purpose)."""
        self._buffer.clear()
        self._db.execute("DELETE FROM records")
        self._db.execute("PRAGMA incremental_vacuum")

    def records(self) -> Iterator[JournalRecord]:
        """The journaled run's records in order (none if there is no run)."""
        try:
            rows = self._db.execute("SELECT body FROM records ORDER BY seq").fetchall()
        except sqlite3.Error as exc:
            raise JournalError(f"cannot read the journal {self.path}: {exc}") from None
        for seq, (body,) in enumerate(rows, 1):
            try:
                yield _ADAPTER.validate_json(body)
            except ValidationError as exc:
                raise JournalError(f"record {seq} of the journal {self.path} is not valid: "
                                   f"{exc.errors(include_url=False)[0]['msg']}") from None

    def count(self) -> int:
        """How many records are committed."""
        return int(self._db.execute("SELECT COUNT(*) FROM records").fetchone()[0])

    def close(self) -> None:
        """Commit what is buffered and close the database."""
        self.commit()
        self._db.close()
