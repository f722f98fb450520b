"""Crash benchmark: the gateway is killed with SIGKILL at random points and restarted.

The gateway runs as its own OS process (``python -m gateway serve --config C --journal J
--port P``, the same command line every time); a simulated fleet (``sim_clients.fleet``, in this
process) executes a 1-robust random plan over real websockets. First an undisturbed run gives
the baseline SOC; then runs of the same plan are executed while the gateway is killed at
random moments (``--kills`` in all, drawn with ``--seed``) and restarted at once with the same
command line; robots reconnect by themselves. Each disturbed run is checked:

* ``resumed``: restarts after which the gateway carried on with the run (``/healthz`` says
  ``running``, not ``empty``/``loaded``); ``from_snapshot``: kills that found the journal
  compacted (it starts with the snapshot of a replan, ``--policy random``);
* ``lost``: completions the robots made that the gateway's trace lacks at the end (and, for a
  run that never completes, the plan's actions it did not complete);
* ``duplicated``: actions a robot executed more than once;
* ``collisions``: what the independent trace checker (``tracecheck``) finds in the trace,
  plus its ``errors`` as ``trace_errors``;
* ``soc_ratio``: the disturbed runs' mean SOC over the baseline's. Downtime is in it: the
  robots wait for the gateway, whose plan time goes on while it is down (``mean_down_s``:
  from the kill to the restarted process answering ``/readyz``, mostly Python's start-up).

``--vda5050``: the robots are simulated VDA 5050 vehicles on a private mosquitto, driven by the
gateway's ``[vda5050]`` master control (duplicates and losses counted from the edges the
vehicles drove; docs/vda5050.md); with ``--lifelong`` too, a shift of them (``errands_twice``:
picks and drops a vehicle ran twice).

Prints ONE line (``--json``: a JSON object with the keys above).

    .venv/bin/python bench/crash.py --kills 20 --seed 1 --json

``--lifelong``: a warehouse shift instead (tasks from the task list, and a batch submitted
through the task API and retried with its idempotency key after each restart), killed every
``--every`` x U(0.5, 1.5) seconds; the same shift must go on after each restart. Besides
``resumed``, ``lost``, ``duplicated``, ``collisions`` and ``trace_errors``: ``renumbered``
(a second shift start in the trace, plan time going back, a segment or action number
repeated or skipped), ``run_ids`` (distinct run ids robots were sent: 1), ``finished_twice``
and ``robot_changed`` (tasks that finished twice, or changed robots once started),
``retry_created``, ``event_gaps`` (task event ids), and ``throughput_ratio``: tasks finished
per minute of plan time against an undisturbed shift of the same fleet (the downtime is in it).
``from_snapshot`` counts the kills that found the shift's journal compacted into a snapshot
(every 60 segments by default: the gateway's ``snapshot_segments``).

    .venv/bin/python bench/crash.py --lifelong --kills 10 --seed 1 --json
"""

from __future__ import annotations

import fleetgate.userio.script  # noqa: F401 (first: Ctrl-C while importing is one line)

# isort: split

import asyncio
import contextlib
import itertools
import json
import os
import random
import resource
import signal
import socket
import sqlite3
import statistics
import subprocess
import sys
import tempfile
import time
import urllib.error
import urllib.request
from collections import Counter
from collections.abc import Sequence
from dataclasses import dataclass
from functools import partial
from pathlib import Path
from typing import Any

from fleetgate.userio import children
from fleetgate.userio.exits import CommandParser, run_main
from gateway.planning.grid import Cell, Grid
from gateway.planning.lorr import warehouse_problem
from gateway.planning.movingai import write_map
from gateway.planning.plan import Plan
from gateway.planning.random_plans import open_grid, random_plan
from gateway.server.clock import LoopClock
from gateway.server.config import GatewayConfig, LifelongSettings
from gateway.vda5050.config import Vda5050Config
from protocol import LoadPlan, Ok, OperatorCommand, Start, decode, encode
from protocol.messages import parse_action_id
from protocol.vda5050.master import parse_order_id
from sim_clients.connect import websocket_connector
from sim_clients.fleet import SimFleet
from sim_clients.mosquitto import LocalBroker
from sim_clients.vda_fleet import (
    driven_actions,
    make_vehicles,
    run_fleet,
    shift_starts,
    vda_config,
)
from sim_clients.vda_vehicle import VdaVehicle
from sim_clients.world import World
from tracecheck import check_trace, read_trace

OPERATOR = "demo-operator"


def limit_files(size: int) -> None:
    """In a child before ``exec``: files it writes cannot grow beyond ``size`` bytes (the write
    fails with ``EFBIG``; ``SIGXFSZ``, which would kill it instead, is ignored)."""
    signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
    resource.setrlimit(resource.RLIMIT_FSIZE, (size, size))


START_CPU_S = 30.0
"""A gateway that used this much CPU without becoming ready is stuck: a start, a replay or a
refusal takes about 1.5 s of it. Counted in CPU, not wall time: on a loaded machine a niced
start waits its turn (29 s of wall time for 1.4 s of CPU at load 15), which is not a fault."""
START_WALL_S = 240.0
"""A gateway that neither became ready nor exited within this wall time is stuck (one that
waits without using CPU: a deadlock)."""


def cpu_s(pid: int) -> float:
    """CPU seconds (user and system) the process ``pid`` has used (0.0 where ``/proc`` cannot
    tell: then only :data:`START_WALL_S` bounds a start)."""
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    except (OSError, IndexError):
        return 0.0
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def free_port() -> int:
    """A port that was free a moment ago (the gateway must keep one across restarts)."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


class GatewayProcess:
    """``python -m gateway serve`` with one fixed command line, killed and restarted."""

    def __init__(self, workdir: Path, port: int, speed: float, policy: str,
                 extra: dict[str, Any] | None = None) -> None:
        self.port = port
        self.trace = workdir / "trace.jsonl"
        config = self.config = workdir / "gateway.json"
        config.write_text(json.dumps({"speed": speed, "policy": policy, "trace": str(self.trace),
                                      "ping_interval_s": 2.0, "ping_timeout_s": 2.0,
                                      **(extra or {})}))
        self.journal = workdir / "journal.sqlite"
        self.cmd = [sys.executable, "-m", "gateway", "serve", "--config", str(config),
                    "--journal", str(self.journal), "--port", str(port),
                    "--log-level", "WARNING"]
        self.log_path = workdir / "gateway.log"
        self.log = self.log_path.open("a")
        self.env: dict[str, str] | None = None
        """The process's environment (None: this one's)."""
        self.cwd: Path | None = None
        """The process's working directory (None: this one's); ``-m gateway`` imports the
        gateway found there first (another version's checkout, for a comparison)."""
        self.proc: subprocess.Popen[bytes] | None = None
        self.starts = 0
        self.down_s: list[float] = []
        """Wall time from each kill to the restarted gateway's readiness."""
        self._killed_at: float | None = None

    def start(self, file_limit: int | None = None) -> None:
        """Start the process and wait until it answers ``/readyz``; ``file_limit``: no file it
        writes may grow beyond that many bytes (``RLIMIT_FSIZE``: a write beyond fails with
        ``EFBIG``, as a full disk fails with ``ENOSPC``)."""
        self.proc = children.spawn(self.cmd, stdout=self.log, stderr=self.log, env=self.env,
                                   cwd=self.cwd,
                                   preexec_fn=None if file_limit is None
                                   else partial(limit_files, file_limit))
        self.starts += 1
        deadline = time.monotonic() + START_WALL_S
        while time.monotonic() < deadline and cpu_s(self.proc.pid) < START_CPU_S:
            if self.proc.poll() is not None:
                self.log.flush()
                tail = self.log_path.read_text().splitlines()[-5:]
                raise RuntimeError(f"the gateway exited with {self.proc.returncode}: "
                                   + " | ".join(tail))
            with contextlib.suppress(OSError), urllib.request.urlopen(
                    f"http://127.0.0.1:{self.port}/readyz", timeout=1):
                if self._killed_at is not None:
                    self.down_s.append(time.perf_counter() - self._killed_at)
                    self._killed_at = None
                return
            time.sleep(0.05)
        raise RuntimeError(f"the gateway did not become ready ({cpu_s(self.proc.pid):.1f} s "
                           f"of CPU used)")

    def health(self) -> dict[str, Any]:
        """What ``/healthz`` says."""
        with urllib.request.urlopen(f"http://127.0.0.1:{self.port}/healthz", timeout=5) as r:
            return dict(json.loads(r.read()))

    def kill(self) -> None:
        """SIGKILL, and reap."""
        if self.proc is not None and self.proc.poll() is None:
            children.kill(self.proc)
            self._killed_at = time.perf_counter()
        self.proc = None

    def journal_starts_with(self) -> str | None:
        """The kind of the journal's first committed record (``snapshot``: compacted at a
        replan), read-only: the journal stays as the killed process left it."""
        db = sqlite3.connect(f"file:{self.journal}?mode=ro", uri=True)
        try:
            row = db.execute("SELECT kind FROM records ORDER BY seq LIMIT 1").fetchone()
        finally:
            db.close()
        return None if row is None else str(row[0])

    def journal_size(self) -> tuple[int, int]:
        """The journal's committed records and its files' bytes (database and WAL)."""
        db = sqlite3.connect(f"file:{self.journal}?mode=ro", uri=True)
        try:
            count = int(db.execute("SELECT COUNT(*) FROM records").fetchone()[0])
        finally:
            db.close()
        files = [self.journal, self.journal.with_name(self.journal.name + "-wal")]
        return count, sum(f.stat().st_size for f in files if f.exists())

    def stop(self) -> None:
        """End the process for good."""
        if self.proc is not None:
            children.stop(self.proc)
        self.proc = None
        self.log.close()


async def _operator(port: int, *commands: OperatorCommand) -> None:
    """Send operator commands, as an operator would; each must be accepted."""
    from websockets.asyncio.client import connect

    async with connect(f"ws://127.0.0.1:{port}/ws",
                       additional_headers={"Authorization": f"Bearer {OPERATOR}"},
                       proxy=None) as ws:
        for msg in commands:
            await ws.send(encode(msg))
            while True:
                reply = decode(await ws.recv())
                if getattr(reply, "ref", None) == msg.msg_id:
                    if not isinstance(reply, Ok):
                        raise RuntimeError(f"the gateway refused {msg.type}: {reply}")
                    break


async def _vehicles_connected(gw: GatewayProcess, robots: int) -> None:
    """Until the gateway reports ``robots`` robots connected (VDA 5050 vehicles)."""
    deadline = time.monotonic() + 60.0
    while (await asyncio.to_thread(gw.health)).get("robots") != robots:
        if time.monotonic() > deadline:
            raise RuntimeError("the VDA 5050 vehicles did not connect")
        await asyncio.sleep(0.1)


def _vda_executed(vehicles: list[VdaVehicle]) -> Counter[tuple[int, int, int]]:
    """How often the vehicles drove each action (plan, robot, index) of the gateway's orders:
    an edge is an action (``orderId`` = ``<plan key>.<first action>``)."""
    executed: Counter[tuple[int, int, int]] = Counter()
    for vehicle in vehicles:
        for order_id, seq in vehicle.driven:
            parsed = parse_order_id(order_id)
            if parsed is not None:
                key, first = parsed
                executed[parse_action_id(f"{key}.{first + (seq - 1) // 2}")] += 1
    return executed


async def _run(gw: GatewayProcess, map_file: Path, plan: Plan, speed: float,
               kills: list[float], rng: random.Random,
               vda: Vda5050Config | None = None) -> dict[str, Any]:
    """One execution of ``plan``; the gateway is killed ``len(kills)`` times, at those
    delays (s) after the start or after the previous restart. With ``vda`` the robots are
    simulated VDA 5050 vehicles on its broker."""
    total = sum(len(p) - 1 for p in plan.paths)
    executed: Counter[tuple[int, int, int]] = Counter()
    completed: set[tuple[int, int, int]] = set()

    def on_event(kind: str, plan_id: int, robot: int, index: int) -> None:
        if kind == "execute":
            executed[(plan_id, robot, index)] += 1
        elif kind == "finished":
            completed.add((plan_id, robot, index))

    fleet = SimFleet(websocket_connector(f"ws://127.0.0.1:{gw.port}/ws"),
                     range(len(plan.paths)), clock=LoopClock(speed), send_state=True,
                     reconnect_delay_s=0.05, seed=rng.randrange(1 << 30))
    fleet.on_event = on_event
    resumed = from_snapshot = 0
    # loaded first: robots are welcomed with their start in this plan, not the last run's
    await _operator(gw.port, LoadPlan(msg_id="load", seq=0, map=str(map_file),
                                      paths=[list(p) for p in plan.paths]))
    vehicles: list[VdaVehicle] = []
    stop_vehicles = asyncio.Event()
    if vda is None:
        await fleet.start()
    else:
        vehicles = make_vehicles(vda, World(), speed=speed, starts={
            r: (path[0], None) for r, path in enumerate(plan.paths)})
        driving = asyncio.create_task(run_fleet(vehicles, vda.broker, stop_vehicles))
    try:
        if vda is None:
            await fleet.wait_connected(timeout=60.0)
        else:
            await _vehicles_connected(gw, len(plan.paths))
        await _operator(gw.port, Start(msg_id="start", seq=0))
        t0 = time.perf_counter()
        for delay in kills:
            await asyncio.sleep(delay)
            if (await asyncio.to_thread(gw.health)).get("gateway") == "done":
                break  # done already: no point in killing
            gw.kill()
            from_snapshot += gw.journal_starts_with() == "snapshot"
            await asyncio.sleep(rng.uniform(0.0, 0.3))  # down for a while
            await asyncio.to_thread(gw.start)
            status = (await asyncio.to_thread(gw.health)).get("gateway")
            resumed += status in ("running", "replanning", "paused", "done")
        deadline = time.perf_counter() + 10.0 + 3.0 * plan.makespan / speed
        while time.perf_counter() < deadline:
            if (await asyncio.to_thread(gw.health)).get("gateway") == "done":
                break
            await asyncio.sleep(0.1)
        wall = time.perf_counter() - t0
    finally:
        await fleet.stop()
        if vda is not None:
            stop_vehicles.set()
            await driving
            executed = _vda_executed(vehicles)
            completed = set(executed)
    records = read_trace(gw.trace)
    report = check_trace(records)
    finished = {(r["plan"], r["robot"], r["action"]) for r in records if r["type"] == "finish"}
    summary = next((r for r in records if r["type"] == "summary"), None)
    # lost: completions the robots made that the gateway's trace lacks, and, if the run did
    # not complete, the plan's actions never completed
    missing = 0 if summary is not None else max(0, total - len(finished))
    return {"resumed": resumed, "from_snapshot": from_snapshot,
            "lost": len(completed - finished) + missing,
            "duplicated": sum(n - 1 for n in executed.values() if n > 1),
            "collisions": len(report.collisions), "trace_errors": len(report.errors),
            "soc_ms": None if summary is None else float(summary["soc_ms"]),
            "errors": len(fleet.stats.errors), "wall_s": wall}


def run(kills: int, seed: int, robots: int, steps: int, speed: float,
        per_run: int, policy: str = "none", vda5050: bool = False) -> dict[str, Any]:
    """The baseline run, then disturbed runs until ``kills`` kills were made; ``vda5050``:
    with simulated VDA 5050 vehicles through a private mosquitto."""
    rng = random.Random(seed)
    plan = random_plan(open_grid(max(6, robots), max(6, robots)), robots, steps, rng)
    run_s = plan.makespan / speed
    with tempfile.TemporaryDirectory() as tmp, contextlib.ExitStack() as broker:
        work = Path(tmp)
        map_file = work / "open.map"
        write_map(open_grid(max(6, robots), max(6, robots)), map_file)
        vda = vda_config(broker.enter_context(LocalBroker()), range(robots)) if vda5050 \
            else None
        gw = GatewayProcess(work, free_port(), speed, policy, extra=None if vda is None else {
            "vda5050": vda.model_dump(mode="json", exclude_none=True)})
        try:
            gw.start()
            base = asyncio.run(_run(gw, map_file, plan, speed, [], rng, vda))
            runs: list[dict[str, Any]] = []
            left = kills
            while left > 0:
                n = min(per_run, left)
                # kill points spread over the run: the first after U(0.1, 1) of a share
                delays = [rng.uniform(0.1, 1.0) * run_s / (n + 1) for _ in range(n)]
                runs.append(asyncio.run(_run(gw, map_file, plan, speed, delays, rng, vda)))
                left -= n
        finally:
            gw.stop()
    made = gw.starts - 1
    socs = [r["soc_ms"] for r in runs if r["soc_ms"] is not None]
    return {"kills": made, "resumed": sum(r["resumed"] for r in runs),
            "from_snapshot": sum(r["from_snapshot"] for r in runs),
            "lost": sum(r["lost"] for r in runs),
            "duplicated": sum(r["duplicated"] for r in runs),
            "collisions": sum(r["collisions"] for r in runs),
            "trace_errors": sum(r["trace_errors"] for r in runs),
            "robot_errors": sum(r["errors"] for r in runs),
            "runs": len(runs), "completed": len(socs),
            "soc_ratio": round(statistics.mean(socs) / base["soc_ms"], 3)
            if socs and base["soc_ms"] else None,
            "baseline_soc_ms": base["soc_ms"], "baseline_lost": base["lost"],
            "mean_down_s": round(statistics.mean(gw.down_s), 2) if gw.down_s else None,
            "robots": robots, "steps": steps, "speed": speed, "seed": seed, "policy": policy}


# ---------------------------------------------------------------------------- lifelong shifts
def _http(port: int, method: str, path: str, body: Any = None) -> tuple[int, Any]:
    """One task API request with operator credentials: (status, JSON body)."""
    req = urllib.request.Request(
        f"http://127.0.0.1:{port}{path}", method=method,
        data=None if body is None else json.dumps(body).encode(),
        headers={"Authorization": f"Bearer {OPERATOR}", "Content-Type": "application/json"})
    try:
        with urllib.request.urlopen(req, timeout=10) as r:
            return r.status, json.loads(r.read())
    except urllib.error.HTTPError as exc:
        return exc.code, json.loads(exc.read() or b"null")


def _task_events(port: int) -> list[dict[str, Any]]:
    """Every task event the gateway kept (its server-sent event stream from the first one),
    each with its event ``id``."""
    last = _http(port, "GET", "/tasks?limit=1")[1]["last_event"]
    out: list[dict[str, Any]] = []
    if not last:
        return out
    req = urllib.request.Request(f"http://127.0.0.1:{port}/tasks/events?after=0",
                                 headers={"Authorization": f"Bearer {OPERATOR}"})
    with urllib.request.urlopen(req, timeout=30) as r:
        fields: dict[str, str] = {}
        for raw in r:
            line = raw.decode().rstrip("\r\n")
            if line:
                name, _, value = line.partition(":")
                fields[name] = value.lstrip(" ")
            elif "data" in fields:
                out.append({**json.loads(fields["data"]), "id": int(fields["id"])})
                fields = {}
                if out[-1]["id"] == last:
                    return out
    return out


def shift_defects(records: list[dict[str, Any]]) -> dict[str, int]:
    """What a lifelong shift's trace shows went wrong: ``collisions`` and other ``trace_errors``
    (tracecheck; a shift cut off by a shutdown, with actions running and no summary, is not
    an error), ``renumbered`` (a second shift start, plan time going back, a segment or action
    number repeated or skipped), ``dispatched_twice`` and ``actions_run``."""
    report = check_trace(records)
    errors = [e for e in report.errors if e != "no summary record"
              and not (e.startswith("robots ") and " never finished " in e)]
    times = [float(r["t_ms"]) for r in records if "t_ms" in r]  # (a summary has none)
    segments = [r["segment"] for r in records if r["type"] == "segment"]
    dispatched = [(r["robot"], r["action"]) for r in records if r["type"] == "dispatch"]
    numbers: dict[int, list[int]] = {}
    for robot, action in dispatched:
        numbers.setdefault(robot, []).append(action)
    renumbered = (abs([r["type"] for r in records].count("plan") - 1)
                  + sum(1 for a, b in itertools.pairwise(times) if b < a)
                  + (segments != list(range(len(segments))))
                  + sum(sorted(set(ns)) != list(range(len(set(ns))))
                        for ns in numbers.values()))
    return {"collisions": len(report.collisions), "trace_errors": len(errors),
            "renumbered": renumbered, "dispatched_twice": len(dispatched) - len(set(dispatched)),
            "actions_run": report.actions_run}


@dataclass(frozen=True)
class Progress:
    """A point in a shift by what it did, not by the wall clock (a loaded machine gets there
    later): ``actions`` more robot actions completed and ``tasks`` more tasks finished since
    the shift's start or its last restart."""

    actions: int
    tasks: int = 0


async def lifelong_shift(gw: GatewayProcess, robots: int, speed: float,
                         kills: Sequence[float | Progress], run_s: float | Progress,
                         rng: random.Random, grid: Grid,
                         vda: Vda5050Config | None = None,
                         starts: dict[int, tuple[Cell, int | None]] | None = None,
                         *, progress_timeout_s: float = 300.0) -> dict[str, Any]:
    """A shift of ``robots`` simulated robots on the gateway ``gw`` (started here, in lifelong
    mode, with a task list and a batch submitted through the task API), killed with SIGKILL
    after each delay (s) of ``kills`` and restarted at once; then ``run_s`` more seconds. A
    :class:`Progress` instead of a delay waits until the shift got that far (at most
    ``progress_timeout_s``; ``stalled`` counts the waits that ran out, a shift that did not go
    on). Returns the counts of :func:`shift_defects` and ``resumed``, ``lost`` (completions robots
    made before the last kill that the trace lacks), ``duplicated`` (actions a robot executed
    twice), ``run_ids`` (distinct run ids robots were sent), ``retry_created`` (a retried
    submission that made tasks again), ``tasks_finished`` (and ``finished_at_last_kill``),
    ``finished_twice`` and
    ``robot_changed`` (tasks that finished twice, or whose robot changed once started), the
    shift's plan time and its tasks per plan minute, and the journal's records and size at
    the end (``journal_records``, ``journal_kb``). With ``vda`` the robots are simulated VDA
    5050 vehicles on its broker standing on ``starts``: ``duplicated`` counts actions driven
    twice, ``lost`` actions driven before the last kill that the trace lacks, and
    ``errands_twice`` picks or drops run twice."""
    executed: Counter[tuple[int, int, int]] = Counter()
    completed: set[tuple[int, int]] = set()

    def on_event(kind: str, plan: int, robot: int, index: int) -> None:
        if kind == "execute":
            executed[(plan, robot, index)] += 1
        elif kind == "finished":
            completed.add((robot, index))

    gw.start()
    fleet = SimFleet(websocket_connector(f"ws://127.0.0.1:{gw.port}/ws"), range(robots),
                     clock=LoopClock(speed), send_state=False, reconnect_delay_s=0.05,
                     duration_jitter=0.2, seed=rng.randrange(1 << 30))
    fleet.on_event = on_event
    free = [list(c) for c in grid.free_cells()]
    batch = {"tasks": [{"errands": rng.sample(free, 2)} for _ in range(robots)],
             "idempotency_key": "bench-1"}
    resumed = retry_created = finished_at_kill = from_snapshot = stalled = 0
    before_last_kill: set[tuple[int, int]] = set()
    vehicles: list[VdaVehicle] = []
    stop_vehicles = asyncio.Event()
    if vda is None:
        await fleet.start()
    else:
        vehicles = make_vehicles(vda, fleet.world, speed=speed, starts=starts, jitter=0.2,
                                 seed=rng.randrange(1 << 30))
        driving = asyncio.create_task(run_fleet(vehicles, vda.broker, stop_vehicles))

    def driven() -> set[tuple[int, int]]:
        return {(v.who, n) for v in vehicles for n in driven_actions(v)}

    def actions_done() -> int:
        return len(completed) + len(driven())

    async def tasks_finished() -> int:
        return int((await asyncio.to_thread(
            _http, gw.port, "GET", "/tasks?limit=1"))[1]["counts"]["finished"])

    async def until(point: float | Progress) -> None:
        """Wait ``point`` seconds, or until the shift made that progress since ``mark``."""
        nonlocal stalled
        if not isinstance(point, Progress):
            await asyncio.sleep(point)
            return
        deadline = time.monotonic() + progress_timeout_s
        while actions_done() - mark[0] < point.actions \
                or (point.tasks and await tasks_finished() - mark[1] < point.tasks):
            if time.monotonic() > deadline:
                stalled += 1
                return
            await asyncio.sleep(0.1)

    try:
        if vda is None:
            await fleet.wait_connected(timeout=60.0)
        else:
            await _vehicles_connected(gw, robots)
        await asyncio.to_thread(_http, gw.port, "POST", "/tasks", batch)
        mark = (actions_done(), await tasks_finished())
        for point in kills:
            await until(point)
            finished_at_kill = await tasks_finished()
            gw.kill()
            from_snapshot += gw.journal_starts_with() in ("shift_history", "shift_snapshot")
            before_last_kill = set(completed) | driven()
            await asyncio.sleep(rng.uniform(0.0, 0.3))  # down for a while
            await asyncio.to_thread(gw.start)
            resumed += (await asyncio.to_thread(gw.health)).get("gateway") == "running"
            status, _ = await asyncio.to_thread(_http, gw.port, "POST", "/tasks", batch)
            retry_created += status != 200
            mark = (actions_done(), await tasks_finished())
        await until(run_s)
        events = await asyncio.to_thread(_task_events, gw.port)
        counts = (await asyncio.to_thread(_http, gw.port, "GET", "/tasks?limit=1"))[1]
    finally:
        await fleet.stop()
        if vda is not None:
            stop_vehicles.set()
            await driving
            executed = Counter((0, v.who, n) for v in vehicles for n in driven_actions(v))
        gw.stop()
    records = read_trace(gw.trace)
    journal_records, journal_bytes = gw.journal_size()
    finished = {(r["robot"], r["action"]) for r in records if r["type"] == "finish"}
    tasks: dict[int, list[tuple[str, int]]] = {}
    for e in events:
        tasks.setdefault(e["task"], []).append((e["state"], e["robot"]))
    plan_ms = max((float(r["t_ms"]) for r in records if "t_ms" in r), default=0.0)
    done = int(counts["counts"]["finished"])
    defects = shift_defects(records)
    defects["renumbered"] += len(list(gw.trace.parent.glob(gw.trace.name + ".*")))  # new shift
    return {**defects, "resumed": resumed, "from_snapshot": from_snapshot,
            "finished_at_last_kill": finished_at_kill,
            "lost": len(before_last_kill - finished),
            "duplicated": sum(n - 1 for n in executed.values() if n > 1),
            "run_ids": len({aid.split(".")[0] for aid in fleet.stats.received}
                           | {o.split(".")[0] for v in vehicles for o, _ in v.driven}),
            "errands_twice": sum(len(v.node_actions_run) - len(set(v.node_actions_run))
                                 for v in vehicles),
            "retry_created": retry_created, "stalled": stalled,
            "robot_errors": len(fleet.stats.errors) + sum(len(v.errors) for v in vehicles),
            "event_gaps": sum(1 for i, e in enumerate(events, 1) if e["id"] != i),
            "tasks_finished": done,
            "finished_twice": sum(1 for s in tasks.values()
                                  if [st for st, _ in s].count("finished") > 1),
            "robot_changed": sum(1 for s in tasks.values()
                                 if len({r for st, r in s if st in ("started", "finished")}) > 1),
            "plan_ms": plan_ms, "tasks_per_min": done * 60_000.0 / plan_ms if plan_ms else 0.0,
            "journal_records": journal_records, "journal_kb": journal_bytes // 1024}


def lifelong_config(gw: GatewayProcess, robots: int, warehouse: tuple[int, int],
                    snapshot_segments: int | None = None) -> None:
    """Turn ``gw``'s configuration into a shift of ``robots`` in a generated warehouse (its
    journal compacted every ``snapshot_segments`` segments; None: the default)."""
    cfg = json.loads(gw.config.read_text())
    compact = {} if snapshot_segments is None else {"snapshot_segments": snapshot_segments}
    gw.config.write_text(json.dumps({**cfg, "map": None, "autostart": True, "lifelong": {
        "robots": robots, "warehouse": list(warehouse), **compact}}))


def run_lifelong(kills: int, seed: int, robots: int, speed: float,
                 every_s: float, vda5050: bool = False) -> dict[str, Any]:
    """An undisturbed shift (the baseline's tasks per plan minute), then a shift killed
    ``kills`` times, every ``every_s`` x U(0.5, 1.5) seconds; ``vda5050``: with simulated
    VDA 5050 vehicles through a private mosquitto."""
    rng = random.Random(seed)
    warehouse = (2, 3) if robots <= 10 else (4, 6)
    grid = warehouse_problem(robots, 0, warehouse, p_delay=0.0).grid
    delays = [every_s * rng.uniform(0.5, 1.5) for _ in range(kills)]
    starts = shift_starts(GatewayConfig(map=None, lifelong=LifelongSettings(
        robots=robots, warehouse=warehouse)))
    with tempfile.TemporaryDirectory() as tmp, contextlib.ExitStack() as broker:
        vda = vda_config(broker.enter_context(LocalBroker()), range(robots)) if vda5050 \
            else None
        out = []
        for name, ks in (("base", []), ("killed", delays)):
            work = Path(tmp) / name
            work.mkdir()
            gw = GatewayProcess(work, free_port(), speed, "none", extra=None if vda is None
                                else {"vda5050": vda.model_dump(mode="json",
                                                                exclude_none=True)})
            lifelong_config(gw, robots, warehouse)
            # the baseline runs as long (wall) as the killed shift runs between kills
            out.append(asyncio.run(lifelong_shift(gw, robots, speed, ks,
                                                  sum(delays) if not ks else every_s,
                                                  rng, grid, vda, starts)))
            out[-1]["mean_down_s"] = round(statistics.mean(gw.down_s), 2) if gw.down_s \
                else None
    base, shift = out
    keys = ("resumed", "from_snapshot", "lost", "duplicated", "collisions", "trace_errors",
            "renumbered", "dispatched_twice", "run_ids", "retry_created", "event_gaps",
            "finished_twice", "robot_changed", "robot_errors", "errands_twice",
            "tasks_finished", "actions_run",
            "mean_down_s", "plan_ms", "journal_records", "journal_kb")
    return {"kills": kills, **{k: shift[k] for k in keys},
            "throughput_ratio": round(shift["tasks_per_min"] / base["tasks_per_min"], 3)
            if base["tasks_per_min"] else None,
            "baseline_tasks_finished": base["tasks_finished"],
            "baseline_defects": sum(base[k] for k in ("lost", "duplicated", "collisions",
                                                       "trace_errors", "renumbered")),
            "robots": robots, "speed": speed, "seed": seed, "lifelong": True,
            "vda5050": vda5050}


def main() -> int:
    """Parse arguments and run."""
    p = CommandParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--kills", type=int, default=10)
    p.add_argument("--seed", type=int, default=1)
    p.add_argument("--robots", type=int, default=10)
    p.add_argument("--steps", type=int, default=30, help="plan steps per robot")
    p.add_argument("--speed", type=float, default=5.0,
                   help="plan time per real time (actions last 1000/speed ms)")
    p.add_argument("--kills-per-run", type=int, default=5)
    p.add_argument("--policy", choices=["none", "random"], default="none",
                   help="the gateway's replanning policy (random: one replan per run at a "
                        "random time, so kills also hit replans)")
    p.add_argument("--lifelong", action="store_true",
                   help="kill a lifelong shift (tasks streaming) instead of one-shot runs")
    p.add_argument("--every", type=float, default=3.0,
                   help="--lifelong: seconds between kills (x U(0.5, 1.5))")
    p.add_argument("--vda5050", action="store_true",
                   help="the robots are simulated VDA 5050 vehicles (a private mosquitto)")
    p.add_argument("--json", action="store_true", help="print the result as one JSON line")
    args = p.parse_args()
    if args.kills < 0 or args.robots < 1 or args.steps < 1 or args.kills_per_run < 1 \
            or args.every <= 0:
        p.error("--kills >= 0, --robots, --steps and --kills-per-run >= 1, --every > 0")
    if args.lifelong:
        result = run_lifelong(args.kills, args.seed, args.robots, args.speed, args.every,
                              args.vda5050)
    else:
        result = run(args.kills, args.seed, args.robots, args.steps, args.speed,
                     args.kills_per_run, args.policy, args.vda5050)
    if args.json:
        print(json.dumps(result))
    elif args.lifelong:
        print(f"{result['kills']} kills of a shift: {result['resumed']} resumed, "
              f"{result['lost']} lost, {result['duplicated']} duplicated, "
              f"{result['collisions']} collisions, {result['finished_twice']} tasks finished "
              f"twice; throughput {result['throughput_ratio']}x the undisturbed shift's")
    else:
        print(f"{result['kills']} kills: {result['resumed']} resumed, {result['lost']} lost, "
              f"{result['duplicated']} duplicated, {result['collisions']} collisions; SOC "
              f"{result['soc_ratio']}x the undisturbed run's")
    return 0


if __name__ == "__main__":
    run_main("bench/crash.py", main)
