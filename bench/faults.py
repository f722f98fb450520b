"""Fault campaign: what a journaled gateway does after each kind of fault (issue 26).

Each trial runs ``python -m gateway serve`` as its own process (a one-shot run of a random
plan, or a lifelong shift fed task batches through the task API, each retried later with its
idempotency key) with simulated robots that implement only the MUST rules of docs/protocol.md
(``SimFleet(must_only=True)``: no repeated ``finished``), injects one fault, restarts the
gateway with the same command line and checks the outcome. Fault kinds:

* ``sigkill``: SIGKILL at a random moment;
* ``power_cut``: SIGKILL, then the last 1-60 records dropped (none of a synced commit: those
  survive a power cut);
* ``enospc``: the journal's file system fills up (a small tmpfs filled with zeros when this
  process may mount one, else the gateway restarted with ``RLIMIT_FSIZE`` at its files' sizes:
  a write beyond fails at the lowest layer); the gateway must stop by itself (exit 74), then
  the space is freed and it is restarted;
* ``eio_sync``: ``fsync``/``fdatasync`` fail with EIO (``bench/eio_shim.c`` preloaded, built
  with ``cc``; the kind is skipped without one); the gateway must stop by itself (exit 74);
* ``record_bitflip`` / ``record_edit``: SIGKILL, then one bit flipped in one record (its body or
  checksum), or one field of one record changed to another valid value;
* ``wal_bitflip`` / ``wal_delete``: SIGKILL, then 20 bits flipped in the WAL's frames, or the
  WAL deleted;
* ``poison``: an operator sends ``set_threshold`` with ``1e999``, ``Infinity`` or ``NaN`` (must
  be refused), then SIGKILL.

Per kind: ``trials``; ``exact_resumes`` (the restarted gateway went on and the outcome is
exact: the run completes, or the shift moves on); ``clean_refusals`` (it refused to start with
exit 2 and one line); ``silent_wrong`` (it went on, but something is wrong: an acknowledged
task or operator setting lost, an action lost or executed twice, a collision or another
tracecheck error, a poison value accepted); ``hung`` (it went on but the run or shift
completed no action for ``STALL_S``, or its start neither became ready nor exited, or a
disk/sync failure left it running); ``unclean`` (a start that failed any other way: a
traceback, another exit code); ``acknowledged_lost``, ``lost`` (completions robots made that
the trace lacks: a one-shot run's once it is done, a shift's after waiting up to ``STALL_S``
for the reports in flight, robots still connected), ``duplicated``, ``collisions``;
``stopped`` (trials where the gateway stopped itself on the failure, exit 74). Every bound is
on progress (or on the CPU a start used), never on a whole run's wall time: a niced campaign
on a loaded machine is slow, and slow is not wrong.

    nice -n 10 .venv/bin/python bench/faults.py --trials 12 --seed 1 --json

Prints ONE line (``--json``: a JSON object with ``oneshot`` and ``lifelong``, each kind's keys,
``trials`` in all and ``wall_s``; ``exact_ratio``: exact resumes over the trials that could
resume, i.e. all but the clean refusals, against 1.0).
``--keep DIR`` keeps every trial's directory (journal, trace, gateway log, ``trial.json``);
``--summarize DIR...`` runs nothing and prints the same line for the trials kept there (a
campaign split over processes, or stopped before its end).
"""

from __future__ import annotations

import fleetgate.userio.script  # noqa: F401 (first: Ctrl-C while importing is one line)

# isort: split

import asyncio
import contextlib
import json
import math
import os
import random
import shutil
import sqlite3
import subprocess
import sys
import tempfile
import time
from collections import Counter
from collections.abc import Callable, Coroutine
from pathlib import Path
from typing import Any

if not __package__:  # run as a script (python bench/faults.py): import bench.* from the root
    sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from bench.crash import (  # the gateway process, operator and shift checks
    OPERATOR,
    GatewayProcess,
    _http,
    _operator,
    free_port,
    lifelong_config,
    shift_defects,
)
from fleetgate.userio.exits import CommandParser, run_main
from gateway.planning.lorr import warehouse_problem
from gateway.planning.movingai import write_map
from gateway.planning.random_plans import open_grid, random_plan
from gateway.runtime.exits import EXIT_BAD_INPUT, EXIT_JOURNAL
from gateway.runtime.journal import Journal
from gateway.server.clock import LoopClock
from protocol import LoadPlan, SetThreshold, Snapshot, Start, decode
from sim_clients.connect import websocket_connector
from sim_clients.fleet import SimFleet
from tracecheck import check_trace, read_trace

KINDS = ("sigkill", "power_cut", "enospc", "eio_sync", "record_bitflip", "record_edit",
         "wal_bitflip", "wal_delete", "poison")
POISON = ("1e999", "Infinity", "NaN", "-1e999")
STALL_S = 60.0
"""A resumed run or shift that completes no action for this long (wall time) is hung. A
bound on progress, not on the whole run: on a loaded machine a niced run is slow, not hung."""
KEYS = ("trials", "exact_resumes", "clean_refusals", "silent_wrong", "hung", "unclean",
        "acknowledged_lost", "lost", "duplicated", "collisions", "stopped")


# ------------------------------------------------------------------------ the faults
def drop_tail(journal: Path, k: int) -> int:
    """Drop the last ``k`` records, but none that a synced commit made durable (those survive
    a power cut: the journal's seal says how many); returns how many were dropped."""
    opened = Journal(journal)
    synced = opened.synced()
    opened.close()
    with sqlite3.connect(journal) as db:
        rows = db.execute("SELECT seq FROM records ORDER BY seq").fetchall()
        cut = max(synced, len(rows) - k)
        if cut < len(rows):
            db.execute("DELETE FROM records WHERE seq >= ?", (rows[cut][0],))
        return len(rows) - cut


def _edit_value(value: Any, rng: random.Random) -> Any:
    """Another valid value of the same type."""
    if isinstance(value, bool):
        return not value
    if isinstance(value, int):
        return value + rng.choice((-1, 1))
    if isinstance(value, float):
        return value + rng.choice((-1.0, 1.0, 100.0))
    if isinstance(value, str):
        others = {"started": "finished", "finished": "started", "queued": "cancelled",
                  "tick": "pause"}
        return others.get(value, value + "x")
    return value


def damage_record(journal: Path, rng: random.Random, edit: bool) -> str:
    """Flip one bit of one record (body or checksum), or change one field of one record."""
    with sqlite3.connect(journal) as db:
        rows = db.execute("SELECT seq, body, chain FROM records").fetchall()
        seq, body, chain = rng.choice(rows)
        if edit:
            rec = json.loads(body)
            fields = [k for k, v in rec.items() if k != "kind" and isinstance(
                v, bool | int | float | str)]
            if not fields:
                return "no field"
            key = rng.choice(fields)
            rec[key] = _edit_value(rec[key], rng)
            db.execute("UPDATE records SET body = ? WHERE seq = ?", (json.dumps(rec), seq))
            return f"record {seq}: {key}"
        column, text = ("body", body) if rng.random() < 0.8 else ("chain", chain)
        at = rng.randrange(len(text))
        flipped = chr(ord(text[at]) ^ (1 << rng.randrange(5)))
        db.execute(f"UPDATE records SET {column} = ? WHERE seq = ?",
                   (text[:at] + flipped + text[at + 1:], seq))
        return f"record {seq}: {column}"


def damage_wal(journal: Path, rng: random.Random, delete: bool) -> str:
    """Flip 20 bits in the WAL's frames, or delete it (and its index)."""
    wal = journal.with_name(journal.name + "-wal")
    if not wal.exists() or wal.stat().st_size <= 32:
        return "no wal"
    if delete:
        wal.unlink()
        journal.with_name(journal.name + "-shm").unlink(missing_ok=True)
        return "deleted"
    data = bytearray(wal.read_bytes())
    for _ in range(20):
        data[rng.randrange(32, len(data))] ^= 1 << rng.randrange(8)
    wal.write_bytes(bytes(data))
    return "flipped"


class Disk:
    """The journal's file system: a tmpfs this process mounted (filled to provoke ENOSPC), or
    a plain directory (then ENOSPC is ``RLIMIT_FSIZE`` on a restarted gateway)."""

    def __init__(self, where: Path) -> None:
        self.dir = where
        where.mkdir()
        try:
            self.mounted = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=64m", "tmpfs",
                                           str(where)], capture_output=True).returncode == 0
        except BaseException:  # Ctrl-C while mounting: the mount may be in place all the same
            subprocess.run(["umount", "-l", str(where)], capture_output=True)
            raise
        self.filler = where / "filler"

    def fill(self) -> None:
        """Leave no free block."""
        chunk = b"\0" * (1 << 20)
        with contextlib.suppress(OSError), self.filler.open("wb") as f:
            while True:
                f.write(chunk)
                f.flush()

    def free(self) -> None:
        """Give the space back."""
        self.filler.unlink(missing_ok=True)

    def close(self, keep: bool = False) -> None:
        """Unmount a tmpfs (``keep``: its journal files copied to ``<dir>-kept`` first)."""
        if self.mounted and keep:
            shutil.copytree(self.dir, self.dir.with_name(self.dir.name + "-kept"),
                            ignore=shutil.ignore_patterns("filler"), dirs_exist_ok=True)
        if self.mounted:
            subprocess.run(["umount", "-l", str(self.dir)], capture_output=True)


def eio_shim(work: Path) -> Path | None:
    """Build ``bench/eio_shim.c`` (None: no C compiler)."""
    cc = shutil.which("cc") or shutil.which("gcc")
    if cc is None:
        return None
    out = work / "eio_shim.so"
    src = Path(__file__).with_name("eio_shim.c")
    done = subprocess.run([cc, "-shared", "-fPIC", "-o", str(out), str(src), "-ldl"],
                          capture_output=True)
    return out if done.returncode == 0 else None


# ------------------------------------------------------------------------ restarts
def wait_exit(gw: GatewayProcess, timeout_s: float) -> int | None:
    """The exit code of a gateway that stops by itself within ``timeout_s`` (None: it did not)."""
    assert gw.proc is not None
    try:
        code = gw.proc.wait(timeout_s)
    except subprocess.TimeoutExpired:
        return None
    gw.proc = None
    return code


def restart(gw: GatewayProcess) -> str:
    """Start ``gw`` again: "ok", "refused" (exit 2 with one line), "hung" (it neither became
    ready nor exited: see :meth:`GatewayProcess.start`; then it is killed) or "unclean"."""
    gw.log.flush()
    before = gw.log_path.stat().st_size
    try:
        gw.start()
    except RuntimeError:
        if gw.proc is not None and gw.proc.poll() is None:  # neither ready nor exited
            gw.kill()
            return "hung"
        code = gw.proc.returncode if gw.proc is not None else None
        gw.proc = None
        gw.log.flush()
        with gw.log_path.open("rb") as f:
            f.seek(before)
            lines = [ln for ln in f.read().decode(errors="replace").splitlines() if ln.strip()]
        one = [ln for ln in lines if ln.startswith("fleetgate: ")]
        clean = code == EXIT_BAD_INPUT and len(one) == 1 and not any(
            "Traceback" in ln for ln in lines)
        return "refused" if clean else "unclean"
    return "ok"


async def _threshold(port: int) -> float | None:
    """The slack threshold the gateway shows operators."""
    from websockets.asyncio.client import connect

    async with connect(f"ws://127.0.0.1:{port}/ws", proxy=None,
                       additional_headers={"Authorization": f"Bearer {OPERATOR}"}) as ws:
        async with asyncio.timeout(10):
            while True:
                msg = decode(await ws.recv())
                if isinstance(msg, Snapshot):
                    return msg.threshold_ms


async def _poison(port: int, value: str) -> bool:
    """Send ``set_threshold`` with a non-finite value as raw JSON; True if it was refused."""
    from websockets.asyncio.client import connect

    raw = f'{{"v":2,"type":"set_threshold","msg_id":"poison","seq":0,"threshold_ms":{value}}}'
    async with connect(f"ws://127.0.0.1:{port}/ws", proxy=None,
                       additional_headers={"Authorization": f"Bearer {OPERATOR}"}) as ws:
        await ws.send(raw)
        async with asyncio.timeout(10):
            while True:
                text = await ws.recv()
                if '"poison"' in str(text) or '"ref":null' in str(text):
                    return '"type":"ok"' not in str(text)


async def inject(kind: str, gw: GatewayProcess, rng: random.Random, disk: Disk,
                 trigger: Path) -> dict[str, Any]:
    """Inject the fault ``kind`` into the running ``gw``; then restart it. Returns the start's
    outcome ("ok", "refused", "unclean", "hung": a failure it did not stop on) and notes."""
    note: dict[str, Any] = {}
    if kind == "poison":
        note["refused"] = await _poison(gw.port, rng.choice(POISON))
    if kind in ("enospc", "eio_sync"):
        if kind == "eio_sync":
            trigger.touch()
        elif disk.mounted:
            await asyncio.to_thread(disk.fill)
        else:  # restarted with its files capped at their present sizes
            gw.kill()
            sizes = [p.stat().st_size for p in gw.journal.parent.glob(gw.journal.name + "*")]
            await asyncio.to_thread(gw.start, max(sizes) + 4096)
        code = await asyncio.to_thread(wait_exit, gw, 30.0)
        trigger.unlink(missing_ok=True)
        disk.free()
        if code is None:  # it did not notice: take it down for the restart
            gw.kill()
        note["stopped"] = code == EXIT_JOURNAL
        if code is not None and code != EXIT_JOURNAL:
            return {"start": "unclean", **note}
    else:
        gw.kill()
    await asyncio.sleep(rng.uniform(0.0, 0.2))
    if kind == "power_cut":
        note["dropped"] = drop_tail(gw.journal, rng.randint(1, 60))
    elif kind in ("record_bitflip", "record_edit"):
        note["damage"] = damage_record(gw.journal, rng, kind == "record_edit")
    elif kind in ("wal_bitflip", "wal_delete"):
        note["damage"] = damage_wal(gw.journal, rng, kind == "wal_delete")
    return {"start": await asyncio.to_thread(restart, gw), **note}


# ------------------------------------------------------------------------ one trial
async def progressing(goal: Callable[[], Coroutine[Any, Any, bool]],
                      completed: dict[tuple[int, int, int], float]) -> bool:
    """Wait until ``goal()`` holds (True), or until the robots completed no action for
    :data:`STALL_S` (False: hung)."""
    seen, since = len(completed), time.monotonic()
    while not await goal():
        if len(completed) != seen:
            seen, since = len(completed), time.monotonic()
        elif time.monotonic() - since > STALL_S:
            return False
        await asyncio.sleep(0.1)
    return True


def _trace_finishes(trace: Path) -> set[tuple[int, int]]:
    """The (robot, action) finishes in a trace being written (a torn last line skipped)."""
    out = set()
    with contextlib.suppress(OSError), trace.open() as f:
        for line in f:
            with contextlib.suppress(ValueError):
                rec = json.loads(line)
                if rec.get("type") == "finish":
                    out.add((rec["robot"], rec["action"]))
    return out


async def drained(trace: Path, made: set[tuple[int, int]]) -> bool:
    """Wait until every completion in ``made`` is in the trace, for at most :data:`STALL_S`
    (False: some never arrived; the trial counts them lost)."""
    deadline = time.monotonic() + STALL_S
    while not made <= await asyncio.to_thread(_trace_finishes, trace):
        if time.monotonic() > deadline:
            return False
        await asyncio.sleep(0.2)
    return True


def new_gateway(work: Path, speed: float, shim: Path | None, trigger: Path,
                disk: Disk) -> GatewayProcess:
    """A gateway process whose journal is on ``disk`` (and, with ``shim``, whose syncs fail
    while ``trigger`` exists)."""
    gw = GatewayProcess(work, free_port(), speed, "none")
    gw.journal = disk.dir / "journal.sqlite"
    gw.cmd[gw.cmd.index("--journal") + 1] = str(gw.journal)
    if shim is not None:
        gw.env = {**os.environ, "LD_PRELOAD": str(shim),
                  "FLEETGATE_EIO_TRIGGER": str(trigger)}
    return gw


def must_only_fleet(gw: GatewayProcess, robots: int, speed: float, rng: random.Random
                    ) -> tuple[SimFleet, Counter[tuple[int, int, int]],
                               dict[tuple[int, int, int], float]]:
    """Simulated robots for ``gw`` that implement only the MUST rules, with the actions they
    executed (how often) and completed (when: ``time.monotonic``), as (plan, robot, index)."""
    executed: Counter[tuple[int, int, int]] = Counter()
    completed: dict[tuple[int, int, int], float] = {}

    def on_event(kind: str, p: int, r: int, i: int) -> None:
        if kind == "execute":
            executed[(p, r, i)] += 1
        elif kind == "finished":
            completed.setdefault((p, r, i), time.monotonic())

    fleet = SimFleet(websocket_connector(f"ws://127.0.0.1:{gw.port}/ws"), range(robots),
                     clock=LoopClock(speed), send_state=False, reconnect_delay_s=0.05,
                     seed=rng.randrange(1 << 30), must_only=True)
    fleet.on_event = on_event
    return fleet, executed, completed


async def oneshot_trial(kind: str, work: Path, rng: random.Random, shim: Path | None,
                        disk: Disk) -> dict[str, Any]:
    """A one-shot run of a random plan with one fault."""
    speed, robots, steps = 5.0, 5, 24
    grid = open_grid(7, 7)
    plan = random_plan(grid, robots, steps, rng)
    map_file = work / "open.map"
    write_map(grid, map_file)
    trigger = work / "eio"
    gw = new_gateway(work, speed, shim, trigger, disk)
    fleet, executed, completed = must_only_fleet(gw, robots, speed, rng)
    out: dict[str, Any] = {"acknowledged_lost": 0}
    try:
        await asyncio.to_thread(gw.start)
        await _operator(gw.port, LoadPlan(msg_id="load", seq=0, map=str(map_file),
                                          paths=[list(p) for p in plan.paths]))
        await fleet.start()
        await fleet.wait_connected(timeout=60.0)
        threshold = float(rng.randrange(100, 5000))
        await _operator(gw.port, SetThreshold(msg_id="th", seq=0, threshold_ms=threshold),
                        Start(msg_id="start", seq=0))
        run_s = plan.makespan / speed
        await asyncio.sleep(rng.uniform(0.15, 0.6) * run_s)
        out.update(await inject(kind, gw, rng, disk, trigger))
        if out["start"] == "ok":
            if await _threshold(gw.port) != threshold:
                out["acknowledged_lost"] += 1

            async def done() -> bool:
                return (await asyncio.to_thread(gw.health)).get("gateway") == "done"

            out["done"] = await progressing(done, completed)
    finally:
        await fleet.stop()
        gw.stop()
    if out["start"] != "ok":
        return out
    records = read_trace(gw.trace)
    report = check_trace(records)
    finished = {(r["plan"], r["robot"], r["action"]) for r in records if r["type"] == "finish"}
    total = sum(len(p) - 1 for p in plan.paths)
    out.update(lost=len(completed.keys() - finished),
               unfinished=total - len(finished),
               duplicated=sum(n - 1 for n in executed.values() if n > 1),
               collisions=len(report.collisions), trace_errors=len(report.errors))
    return out


async def lifelong_trial(kind: str, work: Path, rng: random.Random, shim: Path | None,
                         disk: Disk) -> dict[str, Any]:
    """A shift fed task batches through the task API, with one fault; every batch answered is
    retried with its key at the end (it must answer 200 with the same ids)."""
    speed, robots, warehouse = 10.0, 4, (2, 3)
    trigger = work / "eio"
    gw = new_gateway(work, speed, shim, trigger, disk)
    lifelong_config(gw, robots, warehouse)
    cfg = json.loads(gw.config.read_text())
    cfg["lifelong"]["task_list"] = False
    gw.config.write_text(json.dumps(cfg))
    grid = warehouse_problem(robots, 0, warehouse, p_delay=0.0).grid
    free = [[x, y] for x, y in grid.free_cells()]
    fleet, executed, completed = must_only_fleet(gw, robots, speed, rng)
    acked: dict[str, list[int]] = {}
    batches: dict[str, Any] = {}
    made: set[tuple[int, int]] = set()
    out: dict[str, Any] = {"acknowledged_lost": 0}

    async def feed(stop: asyncio.Event) -> None:
        n = 0
        while not stop.is_set():
            key = f"b{n}"
            batches[key] = {"tasks": [{"errands": [rng.choice(free), rng.choice(free)]}
                                      for _ in range(3)], "idempotency_key": key}
            with contextlib.suppress(OSError, ValueError):
                status, body = await asyncio.to_thread(_http, gw.port, "POST", "/tasks",
                                                       batches[key])
                if status in (200, 201):
                    acked[key] = [t["id"] for t in body["tasks"]]
            n += 1
            await asyncio.sleep(0.15)

    try:
        await asyncio.to_thread(gw.start)
        await fleet.start()
        await fleet.wait_connected(timeout=60.0)
        stop = asyncio.Event()
        feeding = asyncio.ensure_future(feed(stop))
        await asyncio.sleep(rng.uniform(1.0, 3.0))
        stop.set()
        await feeding
        out.update(await inject(kind, gw, rng, disk, trigger))
        if out["start"] == "ok":
            before = len(completed)

            async def moved_on() -> bool:
                return len(completed) >= before + 3

            out["done"] = await progressing(moved_on, completed)
            for key, ids in acked.items():
                status, body = await asyncio.to_thread(_http, gw.port, "POST", "/tasks",
                                                       batches[key])
                if status != 200 or [t["id"] for t in body["tasks"]] != ids:
                    out["acknowledged_lost"] += len(ids)
            # every completion made so far must reach the trace (the robots stay connected
            # meanwhile: a report in flight is not cut off by their stop)
            made = {(r, i) for (_, r, i) in completed}
            out["drained"] = await drained(gw.trace, made)
    finally:
        await fleet.stop()
        gw.stop()
    out["acked"] = len(acked)
    if out["start"] != "ok":
        return out
    records = read_trace(gw.trace)
    defects = shift_defects(records)
    # a shift's action numbers go on across segments: (robot, action) names an action
    finished = {(r["robot"], r["action"]) for r in records if r["type"] == "finish"}
    out.update(lost=len(made - finished),
               duplicated=sum(n - 1 for n in executed.values() if n > 1)
               + defects["dispatched_twice"],
               collisions=defects["collisions"],
               trace_errors=defects["trace_errors"] + defects["renumbered"])
    return out


# ------------------------------------------------------------------------ the campaign
def classify(kind: str, trial: dict[str, Any]) -> dict[str, int]:
    """One trial's contribution to its kind's keys."""
    row = dict.fromkeys(KEYS, 0)
    row["trials"] = 1
    row["stopped"] = int(bool(trial.get("stopped")))
    start = trial["start"]
    if start == "refused":
        row["clean_refusals"] = 1
        return row
    if start != "ok":
        row["unclean" if start == "unclean" else "hung"] = 1
        return row
    for key in ("acknowledged_lost", "lost", "duplicated", "collisions"):
        row[key] = int(trial.get(key, 0))
    wrong = (any(row[k] for k in ("acknowledged_lost", "lost", "duplicated", "collisions"))
             or trial.get("trace_errors", 0) or (kind == "poison" and not trial["refused"]))
    if wrong:
        row["silent_wrong"] = 1
    elif not trial.get("done"):
        row["hung"] = 1
    else:
        row["exact_resumes"] = 1
    return row


def campaign(mode: str, trials: int, seed: int, kinds: tuple[str, ...],
             keep: Path | None = None) -> dict[str, Any]:
    """``trials`` trials of each of ``kinds`` in ``mode`` ("oneshot" or "lifelong"); with
    ``keep``, every trial's directory (journal, trace, gateway log and ``trial.json``, the
    trial's outcome and its class) stays under that directory."""
    rng = random.Random(f"{seed}-{mode}")
    table: dict[str, dict[str, int]] = {}
    trial_fn: Callable[..., Coroutine[Any, Any, dict[str, Any]]] = (
        oneshot_trial if mode == "oneshot" else lifelong_trial)
    with contextlib.ExitStack() as stack:
        if keep is None:
            tmp = stack.enter_context(tempfile.TemporaryDirectory())
        else:
            keep.mkdir(parents=True, exist_ok=True)
            tmp = str(keep)
        shim = eio_shim(Path(tmp))
        for kind in kinds:
            if kind == "eio_sync" and shim is None:
                continue
            row = dict.fromkeys(KEYS, 0)
            for t in range(trials):
                work = Path(tmp) / f"{mode}-{kind}-{t}"
                work.mkdir(exist_ok=keep is not None)
                disk = Disk(work / "disk")
                trial: dict[str, Any]
                try:
                    trial = asyncio.run(trial_fn(kind, work, random.Random(rng.random()),
                                                 shim, disk))
                except Exception as exc:  # a trial that broke: counted, never hidden
                    trial = {"start": "unclean", "error": f"{type(exc).__name__}: {exc}"}
                    print(f"{mode} {kind} trial {t}: {trial['error']}", file=sys.stderr)
                finally:
                    disk.close(keep is not None)
                verdict = classify(kind, trial)
                (work / "trial.json").write_text(json.dumps({"trial": trial,
                                                             "class": verdict}, default=str))
                for key, value in verdict.items():
                    row[key] += value
            table[kind] = row
    return table


def summarize(dirs: list[Path]) -> dict[str, Any]:
    """The campaign's table from the ``trial.json`` of every trial kept under ``dirs`` (by
    ``--keep``; a campaign stopped before its end included): mode -> kind -> keys."""
    result: dict[str, Any] = {}
    for trial in sorted(f for d in dirs for f in d.glob("*/trial.json")):
        mode, kind = trial.parent.name.split("-")[:2]
        row = result.setdefault(mode, {}).setdefault(kind, dict.fromkeys(KEYS, 0))
        for key, value in json.loads(trial.read_text())["class"].items():
            row[key] += value
    return result


def main() -> int:
    """Run the campaign (or sum up kept trials) and print one line."""
    parser = CommandParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--trials", type=int, default=12, help="trials per fault kind and mode")
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--modes", default="oneshot,lifelong")
    parser.add_argument("--kinds", default=",".join(KINDS))
    parser.add_argument("--json", action="store_true")
    parser.add_argument("--keep", type=Path, metavar="DIR",
                        help="keep every trial's directory under DIR (default: deleted)")
    parser.add_argument("--summarize", type=Path, nargs="+", metavar="DIR",
                        help="run nothing: sum up the trials kept under each DIR")
    args = parser.parse_args()
    kinds = tuple(k for k in args.kinds.split(",") if k)
    unknown = [k for k in kinds if k not in KINDS]
    if unknown or args.trials < 1:
        print(f"faults: unknown kinds {unknown} (known: {', '.join(KINDS)})"
              if unknown else "faults: --trials must be >= 1", file=sys.stderr)
        return 2
    t0 = time.perf_counter()
    result: dict[str, Any] = summarize(args.summarize) if args.summarize else {
        mode: campaign(mode, args.trials, args.seed, kinds, args.keep)
        for mode in args.modes.split(",")}
    rows = [row for table in result.values() for row in table.values()]
    total = sum(r["trials"] for r in rows)
    resumable = total - sum(r["clean_refusals"] for r in rows)
    exact = sum(r["exact_resumes"] for r in rows)
    result.update(trials=total, wall_s=None if args.summarize
                  else round(time.perf_counter() - t0, 1),
                  exact_ratio=round(exact / resumable, 3) if resumable else math.nan,
                  baseline_ratio=1.0, seed=None if args.summarize else args.seed)
    if args.json:
        print(json.dumps(result))
    else:
        bad = {k: sum(r[k] for r in rows) for k in
               ("silent_wrong", "hung", "unclean", "acknowledged_lost", "lost", "duplicated",
                "collisions")}
        print(f"faults: {total} trials, {exact} exact resumes, "
              f"{sum(r['clean_refusals'] for r in rows)} clean refusals, {bad}, "
              f"exact_ratio {result['exact_ratio']} (vs 1.0), {result['wall_s']} s")
    return 0


if __name__ == "__main__":
    run_main("bench/faults.py", main)
