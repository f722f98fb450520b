"""The journal refuses what it cannot stand behind (issue 26): records that do not round-trip
(a poison operator value), damaged records (checksums over a hash chain), a second writer (an
OS lock naming its holder) and a configuration that is not the journaled run's; task records
are synced before the commit returns."""

from __future__ import annotations

import contextlib
import math
import os
import shutil
import signal
import sqlite3
import subprocess
import sys
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from pydantic import TypeAdapter

from gateway.runtime.journal import (
    Journal,
    JournalError,
    JournalLock,
    JournalRecord,
    ReportRecord,
    SpeedRecord,
    TaskRecord,
    TimeRecord,
    plain,
    report_json,
)
from gateway.server.config import GatewayConfig, LifelongSettings
from gateway.server.journal_open import open_journal
from protocol import ProtocolError, decode


def _ticks(journal: Journal, n: int) -> None:
    for i in range(n):
        journal.append(TimeRecord(kind="tick", t_ms=100.0 * i))
        journal.commit()


# ------------------------------------------------------------------ defect 3: poison values
@pytest.mark.parametrize("raw", [
    '{"v":2,"type":"set_threshold","msg_id":"a","seq":1,"threshold_ms":1e999}',
    '{"v":2,"type":"set_threshold","msg_id":"a","seq":1,"threshold_ms":Infinity}',
    '{"v":2,"type":"set_threshold","msg_id":"a","seq":1,"threshold_ms":NaN}',
    '{"v":2,"type":"place_intruder","msg_id":"a","seq":1,"cell":[1,1],"duration_ms":1e999}',
])
def test_an_operator_value_that_is_not_finite_is_refused_on_the_wire(raw: str) -> None:
    with pytest.raises(ProtocolError, match="finite number"):
        decode(raw)


def test_a_record_that_does_not_round_trip_never_reaches_the_journal(tmp_path: Path) -> None:
    journal = Journal(tmp_path / "j.sqlite")
    _ticks(journal, 2)
    poison = TaskRecord.model_construct(seq=1, task=1, state="queued", robot=-1, done=0,
                                        t_ms=float("inf"), errands=None, priority=0,
                                        deadline_ms=None, key=None, listed=False, batch=None)
    with pytest.raises(ValueError, match="round-trip"):
        journal.append(poison)
    journal.commit()
    assert [r.kind for r in journal.records()] == ["tick", "tick"]
    with pytest.raises(ValueError):
        GatewayConfig(threshold_ms=float("inf"))
    journal.close()


_VALUES = st.one_of(st.integers(-3, 3), st.booleans(), st.floats(allow_nan=True),
                   st.text(max_size=3), st.sampled_from(["finished", "tick", "started"]))


@pytest.mark.filterwarnings("ignore:Pydantic serializer warnings")  # values of wrong types
@settings(max_examples=300, deadline=None)
@given(st.booleans(), st.lists(_VALUES, min_size=6, max_size=6))
def test_a_record_skipped_by_the_read_back_round_trips(report: bool, values: list[object]
                                                       ) -> None:
    """The hot kinds skip the read-back only when their values round-trip by construction:
    whatever the values, a record :func:`plain` passes is read back as an equal record."""
    rec = ReportRecord.model_construct(**dict(zip(
        ("event", "robot", "plan", "index", "t_ms", "reason"), values, strict=True))) \
        if report else TimeRecord.model_construct(kind=values[0], t_ms=values[1])
    if plain(rec):
        assert TypeAdapter(JournalRecord).validate_json(Journal.encode(rec)) == rec
    else:
        with contextlib.suppress(ValueError):  # refused, or it round-trips the slow way
            Journal.encode(rec)
    ok = ReportRecord.model_construct(event="finished", robot=1, plan=0, index=2, t_ms=5.5)
    assert plain(ok) and not plain(ok.model_copy(update={"t_ms": math.inf}))


@settings(max_examples=300, deadline=None)
@given(st.lists(_VALUES, min_size=6, max_size=6))
def test_a_report_written_without_its_model_reads_back_as_the_record(values: list[object]
                                                                      ) -> None:
    """The owner's reports are written by :func:`report_json` without building the model:
    whatever the values, a body it writes reads back as the record of those values, and it
    writes one for every record :func:`plain` passes (else the caller builds the record)."""
    fields = dict(zip(("event", "robot", "plan", "index", "t_ms", "reason"), values,
                      strict=True))
    rec = ReportRecord.model_construct(**fields)
    body = report_json(*values)  # type: ignore[arg-type]
    assert (body is not None) == plain(rec)
    if body is not None:
        assert TypeAdapter(JournalRecord).validate_json(body) == rec


# ------------------------------------------------------------------ defect 4: damage
def _edit(path: Path, sql: str) -> None:
    db = sqlite3.connect(path)
    db.execute(sql)
    db.commit()
    db.close()


@pytest.mark.parametrize(("edit", "bad"), [
    ("UPDATE records SET body = replace(body, '300.0', '301.0') WHERE seq = 4", 4),
    ("DELETE FROM records WHERE seq = 3", 3),
    ("UPDATE records SET seq = 100 WHERE seq = 2", 2),
])
def test_a_damaged_record_is_refused_with_its_number(tmp_path: Path, edit: str,
                                                     bad: int) -> None:
    path = tmp_path / "j.sqlite"
    journal = Journal(path)
    _ticks(journal, 6)
    journal.close()
    _edit(path, edit)
    with pytest.raises(JournalError, match=f"record {bad} of the journal .* damaged"):
        list(Journal(path).records())


def test_a_lost_tail_is_not_damage_and_the_chain_goes_on_after_a_compaction(
        tmp_path: Path) -> None:
    path = tmp_path / "j.sqlite"
    journal = Journal(path)
    _ticks(journal, 6)
    journal.close()
    _edit(path, "DELETE FROM records WHERE seq > 4")  # a power cut: the last commits lost
    journal = Journal(path)
    assert len(list(journal.records())) == 4
    _ticks(journal, 2)  # the chain continues from the last record on disk
    journal.compact(SpeedRecord(speed=2.0))
    _ticks(journal, 1)
    journal.close()
    assert [r.kind for r in Journal(path).records()] == ["speed", "tick"]


def test_a_failed_commit_is_rolled_back_keeps_its_records_and_fails_the_journal(
        tmp_path: Path) -> None:
    path = tmp_path / "j.sqlite"
    journal = Journal(path)
    _ticks(journal, 2)
    blocker = sqlite3.connect(path, isolation_level=None)
    blocker.execute("BEGIN IMMEDIATE")  # the write lock: the journal's COMMIT cannot have it
    journal.append(TimeRecord(kind="tick", t_ms=500.0))
    with pytest.raises(JournalError, match="cannot write"):
        journal.commit()
    blocker.execute("ROLLBACK")
    blocker.close()
    with pytest.raises(JournalError, match="failed earlier"):
        journal.commit()  # never retried: nothing it acknowledges can be trusted after a failure
    assert journal.failed is not None
    journal.close()
    assert [r.t_ms for r in Journal(path).records()] == [0.0, 100.0]


# ------------------------------------------------------------------ defect 6: configuration
def _config(path: Path, **fields: object) -> GatewayConfig:
    return GatewayConfig(journal=path, **fields)  # type: ignore[arg-type]


def test_a_journal_of_another_configuration_is_refused_naming_the_difference(
        tmp_path: Path) -> None:
    path = tmp_path / "j.sqlite"
    journal, lock = open_journal(_config(path, map="lab", agents=3), fresh=False)
    _ticks(journal, 3)
    journal.close()
    lock.release()
    with pytest.raises(JournalError, match=r"agents '3' \(journal\) vs '4' \(config\)"):
        open_journal(_config(path, map="lab", agents=4), fresh=False)
    with pytest.raises(JournalError, match=r"mode 'one-shot' \(journal\) vs 'lifelong'"):
        open_journal(_config(path, lifelong=LifelongSettings(robots=4)), fresh=False)
    assert Journal(path).count() == 3  # refused, never deleted
    journal, lock = open_journal(_config(path, map="lab", agents=4), fresh=True)
    assert journal.count() == 0
    journal.close()
    lock.release()
    journal, lock = open_journal(_config(path, map="lab", agents=4), fresh=False)
    journal.close()
    lock.release()


# ------------------------------------------------------------------ defect 8: one writer
def test_a_second_writer_is_refused_naming_the_holder_and_a_kill_frees_the_journal(
        tmp_path: Path) -> None:
    path = tmp_path / "j.sqlite"
    holder = subprocess.Popen(
        [sys.executable, "-c", "import sys, time; from pathlib import Path; "
         "from gateway.runtime.journal import JournalLock; JournalLock(Path(sys.argv[1])); "
         "print('held', flush=True); time.sleep(60)", str(path)],
        stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout is not None and holder.stdout.readline() == "held\n"
        with pytest.raises(JournalError, match=f"in use by process {holder.pid} "):
            open_journal(_config(path), fresh=True)  # --fresh does not take it over either
    finally:
        holder.send_signal(signal.SIGKILL)
        holder.wait()
    lock = JournalLock(path)  # the kernel released it with the holder: no stale lock
    with pytest.raises(JournalError, match=f"in use by process {os.getpid()} "):
        JournalLock(path)
    lock.release()


# ------------------------------------------------------------------ defect 7: sync levels
_COMMITS = """
import sys
from pathlib import Path
from gateway.runtime.journal import Journal, TaskRecord, TimeRecord
journal = Journal(Path(sys.argv[1]), checkpoint_period_s=3600.0)
for i in range(5):
    if sys.argv[2] == "task":
        journal.append(TaskRecord(seq=i + 1, task=i + 1, state="queued", robot=-1, done=0,
                                  t_ms=float(i), errands=[1]))
    else:
        journal.append(TimeRecord(kind="tick", t_ms=float(i)))
    journal.commit()
print("committed", flush=True)
"""


def _wal_syncs(tmp_path: Path, kind: str) -> int:
    path = tmp_path / f"{kind}.sqlite"
    trace = tmp_path / f"{kind}.strace"
    subprocess.run(["strace", "-f", "-y", "-e", "trace=fsync,fdatasync", "-o", str(trace),
                    sys.executable, "-c", _COMMITS, str(path), kind], check=True,
                   capture_output=True)
    return sum(f"{path.name}-wal>" in line for line in trace.read_text().splitlines())


@pytest.mark.skipif(shutil.which("strace") is None, reason="strace is not installed")
def test_a_task_record_is_synced_before_its_commit_returns_and_a_tick_is_not(
        tmp_path: Path) -> None:
    # the WAL's creation and the close's checkpoint sync it either way; a task's commit (a
    # 201) syncs each time, a tick's never (robots' reports and ticks: the hello re-sends)
    ticks = _wal_syncs(tmp_path, "tick")
    assert ticks <= 3
    assert _wal_syncs(tmp_path, "task") >= ticks + 5


def test_a_journal_without_checksums_is_refused_and_fresh_makes_it_anew(tmp_path: Path) -> None:
    path = tmp_path / "j.sqlite"
    _edit(path, "CREATE TABLE records (seq INTEGER PRIMARY KEY, kind TEXT NOT NULL, "
                "body TEXT NOT NULL)")
    _edit(path, """INSERT INTO records (kind, body) VALUES ('tick', '{"kind":"tick","t_ms":1}')""")
    with pytest.raises(JournalError, match="earlier fleetgate"):
        open_journal(_config(path), fresh=False)
    journal, lock = open_journal(_config(path), fresh=True)
    _ticks(journal, 2)
    journal.close()
    lock.release()
    assert len(list(Journal(path).records())) == 2


def _task(i: int) -> TaskRecord:
    return TaskRecord(seq=i, task=i, state="queued", robot=-1, done=0, t_ms=float(i),
                      errands=[1])


@pytest.mark.parametrize("damage", ["delete", "flip"])
def test_a_wal_that_lost_synced_records_is_refused(tmp_path: Path, damage: str) -> None:
    """Synced task records live in the WAL (no checkpoint yet); the process dies and the WAL
    is deleted, or bits of its frames are flipped (SQLite then ignores the frames from the
    first bad one: committed records roll back silently). The seal, synced after each synced
    commit, shows what is missing: a one-line refusal, never a resume without them."""
    path = tmp_path / "j.sqlite"
    journal = Journal(path, checkpoint_period_s=3600.0)
    _ticks(journal, 2)
    for i in range(1, 6):
        journal.append(_task(i))
        journal.commit()
    dead = tmp_path / "dead"  # the files as a killed process leaves them
    dead.mkdir()
    for suffix in ("", "-wal", ".seal"):
        shutil.copy(f"{path}{suffix}", f"{dead / path.name}{suffix}")
    journal.close()
    wal = dead / "j.sqlite-wal"
    if damage == "delete":
        wal.unlink()
    else:
        data = bytearray(wal.read_bytes())
        for k in range(20):
            at = 32 + (k * 7919) % (len(data) - 32)
            data[at] ^= 1 << (k % 8)
        wal.write_bytes(bytes(data))
    with pytest.raises(JournalError, match="lost synced records"):
        list(Journal(dead / "j.sqlite").records())
    # the gateway's start checks it before it writes anything (its fingerprint's synced
    # commit would otherwise seal the loss)
    with pytest.raises(JournalError, match="lost synced records"):
        open_journal(_config(dead / "j.sqlite"), fresh=False)
    with pytest.raises(JournalError, match="lost synced records"):
        list(Journal(dead / "j.sqlite").records())
