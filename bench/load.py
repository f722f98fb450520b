"""Load benchmark: R simulated robots over websockets against one gateway in another process.

Workload: an open grid with ~1 robot per 8 cells and a 1-robust plan of ``S`` steps per robot
(``gateway/planning/random_plans.random_plan``: at every step each robot moves to a free neighbour
that nobody stood on the step before, or waits; robots cross all the time, so Type 2 edges
abound). Waits are actions too and an action lasts 1000 ms +- ``--jitter`` (default 20 %, seeded per
robot: real robots are never in lockstep, and a lockstep fleet would send R finishes in the
same millisecond), so the fleet offers ~R actions/s for about S seconds. The gateway runs in
a child process (``--serve``, optionally under cProfile) and starts when every robot is there.
The robots are lean ones (``sim_clients.lean_fleet``: raw websocket frames, one
``asyncio.Protocol`` per robot) in ``--generators N`` processes of their own (default one per
2,500 robots, at most 4), at about a quarter of the gateway's CPU per action
(``robots_cpu_ms_per_action``); ``--generators 0`` runs the full simulated robots
(``sim_clients.fleet``: the shared robot session, pydantic, the websockets client) in this
process instead, which cost about as much CPU as the gateway.

Latency is measured on the robot side, end to end: for every dispatched action, from the
moment the last of its ADG predecessors' ``finished`` messages was handed to its websocket to
the moment the action arrived at its robot (so it includes both network legs, the gateway's
validation, executor and routing, and the robots' own event loop). ``lost`` = plan actions
never received, ``duplicated`` = actions received twice (there is no reconnect here).

Prints ONE JSON line: ``{"robots", "actions", "p50_ms", "p99_ms", "lost", "duplicated", ...}``
plus the gateway's own finish-received -> dispatch-queued p99, the achieved/offered action
rate, ``p99_ratio``: p99 against a 10-robot baseline run measured in the same invocation, and
the machine's 1-minute load average at the run's end and start (``load_1min``,
``load_1min_start``).
``--find-max`` searches the largest fleet with p99 <= 50 ms, nothing lost or duplicated.
Also for information: ``p99_after_step1_ms`` leaves out the dispatches unlocked by the first
finishes (all robots start together, so those come in a burst of ~R / (2 x jitter) per second,
2.5x the steady rate), and the longest garbage-collector pause of each process during the run.

The gateway runs with classic dispatch (``--lookahead 0``, the default here; the gateway's own
default is 1), where every dispatch after the first is released by a finish. With lookahead an
action may be released by its robot's previous dispatch instead, so the run then writes the
gateway's trace and measures only the dispatches a finish released (the dispatch records
right after each finish record), from that finish sent to the action received. ``--trace``
(implied by lookahead) also runs tracecheck on it (``trace_errors``, ``collisions``);
``--journaled`` makes the one run journaled. ``--workers N`` runs the gateway with N worker
processes serving the robots' websockets (docs/workers.md): ``gateway_cpu_ms_per_action`` then
counts the workers' CPU too, split into ``owner_process_cpu_ms_per_action`` and
``workers_cpu_ms_per_action``; the 10-robot baseline runs with the same workers. With
``--pairs P`` (P > 1) it runs P pairs of one-process and worker runs interleaved ABBA and adds
``workers_cpu_per_action_ratio``, ``workers_owner_process_cpu_ratio``, ``workers_p99_ratio``
and ``workers_rate_ratio`` (with workers / without).

    .venv/bin/python bench/load.py --robots 2000 --lookahead 1 --journaled --workers 1 --pairs 2

CPU: ``gateway_cpu_ms_per_action`` is the whole gateway process's CPU time from listening to
the end of the run per plan action; ``owner_cpu_ms_per_action`` only the owner task's own work
(``Engine.cpu_s``: its items, ticks and journal commits; not the connections' framing,
validation and writing, which run in their own tasks), the part that the single writer must do
whatever the other cores take over. ``--uvloop --pairs N`` runs the gateway on uvloop's event
loop (``pip install uvloop``) and on asyncio's, interleaved: ``uvloop_cpu_per_action_ratio``.

    .venv/bin/python bench/load.py --robots 500 --seconds 30 --json
    .venv/bin/python bench/load.py --find-max --seconds 20 --json
    .venv/bin/python bench/load.py --robots 1000 --seconds 20 --profile /tmp/gw.prof

The lean robots speak protocol v3 (no ``ack``: a ``started`` acknowledges its action), or v2
with ``--protocol 2`` (an ``ack`` per action), so a run measures the gateway's v3 path by
default.

``--against DIR --pairs N``: the CPU per action against another version, measured in the same
invocation. ``DIR`` is a checkout of that version (``git worktree add DIR 1045d02``); its own
``bench/load.py --serve`` runs the gateway (with ``DIR`` first on the Python path), N runs of
each side interleaved ABBA on the same plan with this version's robots (speaking the newest
protocol version DIR serves, if older than ``--protocol``: ``against_protocol``). Adds
``cpu_per_action_ratio`` (median gateway CPU per action, this / that: < 1 is leaner),
``p99_against_ratio``, every run's figures and the load average after each run; with
``--journal`` both sides run journaled; with ``--workers W`` both sides run W worker
processes (``owner_process_cpu_per_action_ratio``, ``workers_cpu_per_action_ratio``).

    .venv/bin/python bench/load.py --robots 1000 --seconds 20 --against ../base1045 --pairs 5 --json
    .venv/bin/python bench/load.py --robots 5000 --seconds 30 --lookahead 1 --journaled --json

``--lifelong``: a warehouse shift instead of one plan. The gateway (child process) runs in
lifelong mode on a generated warehouse (about 12 free cells per robot, ``--robots`` turning
robots) with the problem's task list OFF (``task_list = false``): its task pool is fed only by
a simulated WMS in this process (``sim_clients.wms``) through the HTTP task API, ``POST
/tasks`` with the operator's token, an ``Idempotency-Key`` per batch, and the task event
stream to learn which tasks ended. The WMS submits the problem's task list in order and keeps
``reveal`` of them outstanding (LoRR's ``numTasksReveal`` x team size, the number the
Start-Kit keeps revealed) plus a lead of ``reveal / 20`` (at least 8) in the gateway's backlog;
the gateway's pool reveals ``reveal`` at a time, oldest first, so its schedulers see the same
task stream as the Start-Kit's reveal rule gives the virtual-time reference, and the lead
absorbs the WMS's reaction time (``wms_min_lead`` < 0 would mean the pool was short of tasks
for a moment). The shift runs for ``--seconds`` of plan time in real time (actions last 1000
ms x U(1-J, 1+J)), then stops (robots finish what they hold). Reported:
``throughput_ratio`` = tasks finished per minute over the network against the same problem in
virtual time (``run_lifelong``: the same task list revealed by the Start-Kit's rule, one
action per 1000 ms tick, the scheduler's and planner's measured CPU time charged as the LoRR
rules do), measured in the same invocation; ``p99_ms``: robot side, from a robot's
``finished`` handed to its websocket to the arrival of each action the gateway dispatched on
that finish (found in the gateway's trace: the dispatch records that follow the finish
record); ``lost`` (dispatched, never received) and ``duplicated`` (received again, or one
action number under two ids); ``task_api_p99_ms``: the WMS's ``POST /tasks`` round trips
during the shift (the initial fill left out). ``--profile FILE`` profiles the gateway's event
loop thread (CPU time of that thread).

    .venv/bin/python bench/load.py --lifelong --robots 500 --seconds 90 --lookahead 1 --json

``--lifelong --against DIR --pairs N``: the same shift (problem, task feed, this version's
robots) served by this gateway and by DIR's (its ``bench/load.py --serve-lifelong``),
interleaved ABBA: ``cpu_per_action_ratio`` (the gateway process's CPU per action over the
shift, this / that; the planner process is left out on both sides), the same for p99 and tasks
per minute (no virtual-time reference is run).

    .venv/bin/python bench/load.py --lifelong --robots 500 --seconds 30 --against ../main --pairs 2

``--lifelong --vda5050``: the same shift with every robot a simulated VDA 5050 vehicle
(``sim_clients.vda_fleet``, this process, one MQTT connection each) on a private mosquitto,
driven by the gateway's master control (docs/vda5050.md); errands are ``pick`` / ``drop``
node actions that take no time (the virtual-time reference has none). ``lost`` = dispatched
actions no vehicle drove, ``duplicated`` = actions driven twice (from the edges the vehicles
drove), ``picks_and_drops`` the node actions they ran; there is no robot-side p99.

    .venv/bin/python bench/load.py --lifelong --vda5050 --robots 200 --seconds 60 --json
"""

from __future__ import annotations

import fleetgate.userio.script  # noqa: F401 (first: Ctrl-C while importing is one line)

# isort: split

import argparse
import asyncio
import contextlib
import cProfile
import dataclasses
import gc
import importlib
import importlib.util
import json
import math
import os
import pstats
import random
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from collections import Counter
from collections.abc import AsyncIterator, Callable
from pathlib import Path
from typing import Any

import numpy as np

from fleetgate.userio import children
from fleetgate.userio.exits import CommandParser, run_main
from fleetgate.userio.files import check_writable, write_text
from gateway.execution.oneshot.adg import ADG
from gateway.planning.grid import Grid
from gateway.planning.instance import Instance
from gateway.planning.lorr import LorrProblem, warehouse_blocks, warehouse_problem
from gateway.planning.plan import Plan
from gateway.planning.random_plans import open_grid, random_plan
from gateway.runtime.exits import UsageError
from gateway.server.config import GatewayConfig, LifelongSettings, TokensConfig
from gateway.server.gateway import Gateway
from gateway.server.gc_tuning import GC_THRESHOLDS
from gateway.server.items import OwnerCall
from gateway.server.planner import Problem
from gateway.vda5050.broker import BrokerConfig
from gateway.vda5050.transport import VdaTransport
from protocol import PROTOCOL_VERSION, parse_action_id
from sim_clients.connect import websocket_connector
from sim_clients.fleet import FleetStats, SimFleet
from sim_clients.lean_fleet import LeanFleet, LeanStats
from sim_clients.lifelong import LifelongConfig, run_lifelong
from sim_clients.mosquitto import LocalBroker
from sim_clients.vda_fleet import (
    driven_actions,
    make_vehicles,
    run_fleet,
    shift_starts,
    vda_config,
)
from sim_clients.vda_vehicle import VdaVehicle
from sim_clients.wms import Wms
from sim_clients.world import World
from tracecheck import check_trace, read_trace

P99_LIMIT_MS = 50.0
BASELINE_ROBOTS = 10


def workload(robots: int, steps: int, seed: int) -> tuple[int, Plan]:
    """Grid side and a 1-robust plan of ``robots`` walkers over ``steps`` steps."""
    size = max(8, math.ceil(math.sqrt(robots * 8)))
    return size, random_plan(open_grid(size, size), robots, steps, random.Random(seed))


def _raise_fd_limit() -> None:
    _soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    with contextlib.suppress(ValueError, OSError):
        resource.setrlimit(resource.RLIMIT_NOFILE, (hard, hard))


class GcPauses:
    """Longest and total pause of this process's cyclic garbage collector since created or
    :meth:`reset` (the execution: the connection phase does not count)."""

    def __init__(self) -> None:
        self.max_ms = 0.0
        self.total_ms = 0.0
        self._t0 = 0.0
        gc.callbacks.append(self._on_gc)

    def reset(self) -> None:
        """Forget the pauses so far."""
        self.max_ms = self.total_ms = 0.0

    def stop(self) -> None:
        """Stop counting (the collections after the execution are not its pauses)."""
        if self._on_gc in gc.callbacks:
            gc.callbacks.remove(self._on_gc)

    def _on_gc(self, phase: str, _info: dict[str, int]) -> None:
        if phase == "start":
            self._t0 = time.perf_counter()
            return
        pause = (time.perf_counter() - self._t0) * 1000.0
        self.max_ms = max(self.max_ms, pause)
        self.total_ms += pause


# ------------------------------------------------------------------ the gateway process
async def _serve(plan_file: Path, lookahead: int, journal: Path | None,
                 trace: Path | None = None, workers: int = 0) -> dict[str, Any]:
    data = json.loads(plan_file.read_text())
    plan = Plan.of(data["paths"])
    size = int(data["size"])
    grid = Grid(np.ones((size, size), dtype=bool), name=f"open-{size}")
    inst = Instance(grid, tuple(p[0] for p in plan.paths), tuple(p[-1] for p in plan.paths),
                    "load")
    config = GatewayConfig(port=0, map=None, autostart=True, policy="none",
                           ping_interval_s=20.0, ping_timeout_s=20.0, log_level="WARNING",
                           dispatch_lookahead=lookahead, journal=journal, trace=trace,
                           workers=workers)
    pauses = GcPauses()
    gw = Gateway(config)
    gw.engine.meter_cpu = True  # owner_cpu_s
    async with gw:
        def measure(status: str) -> None:  # the execution's pauses, from start to done
            if status == "running":
                pauses.reset()
            elif status == "done":
                pauses.stop()

        # first: the collection that the gateway's own listener lets run once the run is done
        # (gc_tuning.restore_defaults) is not one of the run's pauses
        gw.engine.status_listeners.insert(0, measure)
        gw.engine.load(Problem(inst, "load", plan))
        port = await gw.listen()
        print(port, flush=True)
        pool = gw.workers
        cpu0 = time.process_time()  # from here: connections and the execution, not imports
        owner0 = gw.engine.cpu_s
        workers0 = pool.cpu_s() if pool is not None else 0.0
        soc, _ = await gw.wait_done()
        workers_cpu = pool.cpu_s() - workers0 if pool is not None else 0.0
        lat = sorted(gw.latencies_ms)
        out: dict[str, Any] = {
            "soc_ms": soc, "dispatches": len(lat),
            "cpu_s": time.process_time() - cpu0 + workers_cpu, "workers_cpu_s": workers_cpu,
            "owner_process_cpu_s": time.process_time() - cpu0,
            "owner_cpu_s": gw.engine.cpu_s - owner0,
            "gc_max_ms": round(pauses.max_ms, 1),
            "gateway_p50_ms": statistics.median(lat) if lat else None,
            "gateway_p99_ms": lat[int(0.99 * (len(lat) - 1))] if lat else None}
        j = gw.engine.journal
        if j is not None:
            cp = j.checkpointer
            out["journal"] = {
                "records": j.appended, "commits": j.commits,
                "commit_max_ms": round(j.commit_max_ms, 2), "wal_restarts": j.restarts,
                "checkpoints": cp.passes if cp else 0,
                "wal_max_pages": cp.max_wal_pages if cp else 0}
        return out


def serve_main(plan_file: Path, profile: Path | None, lookahead: int,
               journal: Path | None, uvloop: bool = False, trace: Path | None = None,
               workers: int = 0) -> None:
    """``--serve``: run the gateway until the plan is executed (``uvloop``: on uvloop's event
    loop; ``workers``: its worker processes); print its port, then a JSON line of its own
    measurements."""
    _raise_fd_limit()
    # CPU time, not wall time: on a shared machine wall time would charge preemptions to
    # whatever function happened to run
    profiler = cProfile.Profile(time.process_time) if profile is not None else None
    if profiler is not None:
        profiler.enable()
    factory = None
    if uvloop:
        # optional (pip install uvloop): main() checked that it is there
        factory = importlib.import_module("uvloop").new_event_loop
    with asyncio.Runner(loop_factory=factory) as runner:
        result = runner.run(_serve(plan_file, lookahead, journal, trace, workers))
    if profiler is not None:
        profiler.disable()
        profiler.dump_stats(str(profile))
    print(json.dumps(result), flush=True)


# ------------------------------------------------------------------ the robots (this process)
def latencies_ms(plan: Plan, stats: FleetStats, from_step: int = 0) -> list[float]:
    """Per dispatched action with predecessors (at plan step ``from_step`` or later): last
    predecessor's finish sent -> received (classic dispatch: lookahead 0)."""
    adg = ADG(plan)
    # by (plan, robot, index): a journaled run's ids carry its run id as well
    received = {parse_action_id(a): t for a, t in stats.received.items()}
    finish_sent = {parse_action_id(a): t for a, t in stats.finish_sent.items()}
    out = []
    for v in range(adg.n_vertices):
        if adg.step_of[v] < from_step:
            continue
        preds = adg.pred[adg.pred_ptr[v]:adg.pred_ptr[v + 1]]
        got = received.get((0, adg.robot_of[v], adg.step_of[v]))
        if not preds or got is None:
            continue
        sent = [finish_sent.get((0, adg.robot_of[p], adg.step_of[p])) for p in preds]
        if any(s is None for s in sent):
            continue
        out.append((got - max(s for s in sent if s is not None)) * 1000.0)
    return out


def traced_latencies_ms(records: list[dict[str, Any]], stats: FleetStats, from_step: int = 0
                        ) -> list[float]:
    """Per dispatch a finish released (the gateway's trace has it right after that finish; at
    plan step ``from_step`` or later): that finish sent -> the action received. Exact with
    lookahead too, where an action may be released by its robot's previous dispatch instead
    (then no finish released it and it is not counted)."""
    received = {parse_action_id(a)[1:]: t for a, t in stats.received.items()}
    finish_sent = {parse_action_id(a)[1:]: t for a, t in stats.finish_sent.items()}
    return [(received[d] - finish_sent[f]) * 1000.0 for f, d in unlocked_by_finish(records)
            if d[1] >= from_step and d in received and f in finish_sent]


def cpu_pressure() -> float | None:
    """Share of the last minute in which some task waited for a CPU (Linux PSI), in %: how
    much other load on the machine distorted the latencies."""
    try:
        line = Path("/proc/pressure/cpu").read_text().splitlines()[0]
    except (OSError, IndexError):
        return None
    fields = dict(f.split("=") for f in line.split()[1:])
    return float(fields["avg60"])


_SLEEPER = """
import sys, time
late = []
end = time.perf_counter() + float(sys.argv[1])
while time.perf_counter() < end:
    t = time.perf_counter()
    time.sleep(0.002)
    late.append((time.perf_counter() - t - 0.002) * 1000.0)
late.sort()
print(late[int(0.99 * (len(late) - 1))])
"""
"""A process that only sleeps 2 ms at a time: its 99th percentile of lateness is the
machine's wake-up noise floor during the run (what any latency measured here includes)."""


def _percentile(values: list[float], q: float) -> float:
    ordered = sorted(values)
    return ordered[min(len(ordered) - 1, int(q * len(ordered)))]


@contextlib.asynccontextmanager
async def _connected_fleet(port: int, robots: int, jitter: float) -> AsyncIterator[SimFleet]:
    """A simulated fleet of ``robots`` connected to the gateway on ``port``, stopped on exit."""
    fleet = SimFleet(websocket_connector(f"ws://127.0.0.1:{port}/ws"), range(robots),
                     send_state=True, reconnect_delay_s=1.0, duration_jitter=jitter)
    await fleet.start()
    try:
        await fleet.wait_connected(timeout=120.0)
        # the fleet's objects live until the end: keep the collector's full passes off them
        # (at 2,000 robots one took ~240 ms, a stall every robot's latency would include),
        # and collect rarely, as the gateway does during a run
        gc.freeze()
        gc.set_threshold(*GC_THRESHOLDS)
        yield fleet
    finally:
        await fleet.stop()


async def _drive(port: int, plan: Plan, deadline_s: float, jitter: float
                 ) -> tuple[FleetStats, float, int, float]:
    """Run the fleet until every action was finished (or the deadline); returns the stats,
    the execution's wall time, the number of plan actions and the longest GC pause."""
    total = sum(len(p) - 1 for p in plan.paths)
    async with _connected_fleet(port, len(plan.paths), jitter) as fleet:
        pauses = GcPauses()
        t0 = time.perf_counter()
        end = t0 + deadline_s
        while len(fleet.stats.finish_sent) < total and time.perf_counter() < end:
            await asyncio.sleep(0.2)
        first = min(fleet.stats.received.values(), default=t0)
        last = max(fleet.stats.finish_sent.values(), default=t0)
        return fleet.stats, last - first, total, pauses.max_ms


def newest_version(tree: Path) -> int:
    """The newest protocol version the checkout ``tree`` serves (its
    ``protocol.messages.SUPPORTED_VERSIONS``, imported from there)."""
    out = subprocess.run(
        [sys.executable, "-c", "from protocol.messages import SUPPORTED_VERSIONS as v; "
         "print(max(v))"], env={**os.environ, "PYTHONPATH": str(tree)}, cwd=tree,
        capture_output=True, text=True, check=True)
    return int(out.stdout)


def generators_for(robots: int) -> int:
    """How many lean generator processes load ``robots`` robots by default (one per 2,500
    robots, at most 4): one process's event loop would add its own queueing to the latency."""
    return min(4, max(1, math.ceil(robots / 2500)))


def lean_deadline_s(seconds: int) -> float:
    """How long lean robots run from the first action before they give up (a run served at
    less than a tenth of the offered rate is cut: its robots report errors, its actions are
    lost)."""
    return 10.0 * seconds + 60.0


def lean_main(args: argparse.Namespace) -> None:
    """``--lean-part K/N PLAN OUT``: run the plan's robots ``r % N == K`` as a
    :class:`~sim_clients.lean_fleet.LeanFleet` against ``--port``; write its stats to OUT."""
    _raise_fd_limit()
    plan_file, out = args.lean_files
    k, n = (int(x) for x in args.lean_part.split("/"))
    paths = json.loads(Path(plan_file).read_text())["paths"]
    mine = {r: path for r, path in enumerate(paths) if r % n == k}

    async def go() -> LeanStats:
        fleet = LeanFleet(args.port, mine, args.jitter, args.seed, args.protocol)
        return await fleet.run(lean_deadline_s(args.seconds))

    write_text(out, json.dumps(dataclasses.asdict(asyncio.run(go()))))


def _drive_lean(port: int, plan_file: Path, parts: int, seconds: int, seed: int,
                jitter: float, protocol: int) -> tuple[FleetStats, float, float]:
    """Run the plan's robots in ``parts`` lean generator processes (speaking ``protocol``);
    their merged stats, the execution's wall time and the processes' CPU time during it."""
    outs = [plan_file.with_name(f"robots-{k}.json") for k in range(parts)]
    stats, cpu = FleetStats(), 0.0
    with contextlib.ExitStack() as stack:
        procs = [stack.enter_context(children.running(
            [sys.executable, __file__, "--lean-part", f"{k}/{parts}", "--lean-files",
             str(plan_file), str(out), "--port", str(port), "--seconds", str(seconds),
             "--seed", str(seed), "--jitter", str(jitter), "--protocol", str(protocol)]))
            for k, out in enumerate(outs)]
        for proc, out in zip(procs, outs, strict=True):
            proc.wait(timeout=lean_deadline_s(seconds) + 900.0)  # + connecting, starting
            if proc.returncode != 0 or not out.exists():
                stats.errors.append(f"generator {out.name} exited {proc.returncode}")
                continue
            part = json.loads(out.read_text())
            stats.received.update(part["received"])
            stats.finish_sent.update(part["finish_sent"])
            stats.duplicates += part["duplicates"]
            stats.errors.extend(part["errors"])
            cpu += part["cpu_s"]
    first = min(stats.received.values(), default=0.0)
    last = max(stats.finish_sent.values(), default=0.0)
    return stats, last - first, cpu


def run_once(robots: int, seconds: int, seed: int, jitter: float, lookahead: int = 0,
             profile: Path | None = None, journal: bool = False, tree: Path | None = None,
             generators: int = -1, uvloop: bool = False, trace: bool = False,
             workers: int = 0, protocol: int = PROTOCOL_VERSION) -> dict[str, Any]:
    """One gateway process + one fleet; the measurements as a dict. With ``tree`` (a checkout
    of another version) the gateway process is that version's (its ``bench/load.py --serve``
    with its packages first on the path); the robots are always this version's: ``generators``
    lean generator processes (:mod:`sim_clients.lean_fleet`; < 0: :func:`generators_for`), or
    with 0 the full simulated robots of :mod:`sim_clients.fleet` in this process (the
    latest protocol version; the lean ones speak ``protocol``)."""
    size, plan = workload(robots, seconds, seed)
    if generators < 0:
        generators = generators_for(robots)
    load_start = round(os.getloadavg()[0], 1)
    with tempfile.TemporaryDirectory() as tmp:
        plan_file = Path(tmp) / "plan.json"
        plan_file.write_text(json.dumps({"size": size, "paths": [list(p) for p in plan.paths]}))
        cmd = [sys.executable, str(tree / "bench" / "load.py") if tree else __file__,
               "--serve", str(plan_file), "--lookahead", str(lookahead)]
        if profile is not None:
            cmd += ["--profile", str(profile)]
        if journal:
            cmd += ["--serve-journal", str(Path(tmp) / "journal.sqlite")]
        if uvloop:
            cmd += ["--serve-uvloop"]
        if workers:
            cmd += ["--serve-workers", str(workers)]
        trace_file = Path(tmp) / "trace.jsonl"
        trace = trace or lookahead > 0  # what a finish released is read from the trace
        if trace:
            cmd += ["--serve-trace", str(trace_file)]
        env = {**os.environ, "PYTHONPATH": str(tree)} if tree else None
        # (in ``tree``: its worker processes, started with ``-m``, import from there too)
        with (children.running(cmd, stdout=subprocess.PIPE, text=True, env=env,
                               cwd=tree) as gw,
              children.running([sys.executable, "-c", _SLEEPER, str(seconds)],
                               stdout=subprocess.PIPE, text=True) as sleeper):
            assert gw.stdout is not None
            line = gw.stdout.readline()
            if not line.strip().isdigit():  # e.g. an --against checkout without an option
                raise UsageError(f"the gateway of {tree or 'this checkout'} did not start "
                                 "(its error is above)")
            port = int(line)
            total = sum(len(p) - 1 for p in plan.paths)
            robots_gc_ms: float | None = None
            if generators:
                stats, wall_s, robots_cpu = _drive_lean(port, plan_file, generators, seconds,
                                                        seed, jitter, protocol)
            else:
                cpu0 = time.process_time()
                stats, wall_s, total, robots_gc_ms = asyncio.run(
                    _drive(port, plan, 3.0 * seconds + 60.0, jitter))
                robots_cpu = time.process_time() - cpu0
            try:
                out, _ = gw.communicate(timeout=60)
            except subprocess.TimeoutExpired:  # the robots gave up: the run never ends
                out = ""
            gateway = json.loads(out.strip() or "{}")
            floor = float(sleeper.communicate(timeout=60)[0] or "nan")
        records = read_trace(trace_file) if trace else []
        checked = check_trace(records) if trace else None
    if checked is not None:  # the dispatches each finish released, as the gateway traced them
        lat = traced_latencies_ms(records, stats)
        # with lookahead L a robot holds actions 0..L at the start: its first finish releases
        # action L + 1
        steady = traced_latencies_ms(records, stats, from_step=lookahead + 2)
    else:
        lat = latencies_ms(plan, stats)
        steady = latencies_ms(plan, stats, from_step=2)
    # every robot starts at 0, so the first finishes come within +-jitter of 1 s: a burst of
    # ~R / (2 jitter) per s; later steps spread out to the fleet's steady ~R actions/s
    offered = total / plan.makespan  # actions per second if nobody is ever late
    achieved = total / wall_s if wall_s > 0 else 0.0
    return {"robots": robots, "lookahead": lookahead, "journal": journal, "uvloop": uvloop,
            "protocol": protocol if generators else PROTOCOL_VERSION,
            "workers": workers, "actions": len(stats.received),
            "p50_ms": round(statistics.median(lat), 3) if lat else None,
            "p99_ms": round(_percentile(lat, 0.99), 3) if lat else None,
            "p99_after_step1_ms": round(_percentile(steady, 0.99), 3) if steady else None,
            "lost": total - len(stats.received), "duplicated": stats.duplicates,
            "errors": len(stats.errors), "error_samples": stats.errors[:3],
            **({"trace_errors": len(checked.errors), "collisions": len(checked.collisions)}
               if checked is not None else {}),
            "gateway_p99_ms": gateway.get("gateway_p99_ms"),
            **({"journal_stats": gateway["journal"]} if "journal" in gateway else {}),
            "gateway_cpu_s": round(gateway.get("cpu_s", 0.0), 1),
            "gateway_cpu_ms_per_action": round(1000.0 * gateway.get("cpu_s", 0.0) / total, 3),
            "owner_cpu_ms_per_action": round(1000.0 * gateway["owner_cpu_s"] / total, 4)
            if "owner_cpu_s" in gateway else None,
            **({"owner_process_cpu_ms_per_action":
                round(1000.0 * gateway["owner_process_cpu_s"] / total, 3),
                "workers_cpu_ms_per_action": round(1000.0 * gateway["workers_cpu_s"] / total, 3)}
               if workers else {}),
            "gateway_gc_max_ms": gateway.get("gc_max_ms"),
            "robots_gc_max_ms": None if robots_gc_ms is None else round(robots_gc_ms, 1),
            "generators": generators,
            "robots_cpu_ms_per_action": round(1000.0 * robots_cpu / total, 3),
            "cpu_pressure_pct": cpu_pressure(), "os_wakeup_p99_ms": round(floor, 2),
            "robots_cpu_s": round(robots_cpu, 1), "wall_s": round(wall_s, 1),
            "offered_per_s": round(offered, 1), "achieved_per_s": round(achieved, 1),
            "rate_ratio": round(achieved / offered, 4) if offered else None,
            "load_1min": round(os.getloadavg()[0], 1), "load_1min_start": load_start}


# ------------------------------------------------------------------ lifelong (--lifelong)
def shift_problem(robots: int, seed: int) -> LorrProblem:
    """The warehouse of a lifelong load run: about 12 free cells per robot, no delays."""
    return warehouse_problem(robots, seed, warehouse_blocks(robots), p_delay=0.0)


def shift_reveal(problem: LorrProblem) -> int:
    """Tasks the Start-Kit keeps revealed (and the gateway's pool: ``reveal`` unset)."""
    return max(1, int(problem.num_tasks_reveal * problem.team_size))


def shift_config(robots: int, seed: int, trace: Path | None, lookahead: int, window: int,
                 vda_broker: str | None = None) -> GatewayConfig:
    """The gateway of a lifelong load run; ``vda_broker``: every robot is a VDA 5050 vehicle
    ``fleetgate/sim<r>`` (2.1.0) on that broker."""
    vda = None if vda_broker is None else vda_config(vda_broker, range(robots))
    return GatewayConfig(port=0, map=None, autostart=True, ping_interval_s=20.0,
                         ping_timeout_s=20.0, log_level="WARNING", trace=trace,
                         dispatch_lookahead=lookahead, vda5050=vda,
                         lifelong=LifelongSettings(robots=robots, seed=seed, window=window,
                                                   warehouse=warehouse_blocks(robots),
                                                   task_list=False))


async def _serve_shift(robots: int, seed: int, seconds: float, trace: Path, lookahead: int,
                       window: int, vda_broker: str | None) -> dict[str, Any]:
    config = shift_config(robots, seed, trace, lookahead, window, vda_broker)
    async with Gateway(config) as gw, contextlib.AsyncExitStack() as vehicles:
        if config.vda5050 is not None:
            await vehicles.enter_async_context(VdaTransport(gw, config.vda5050))
        run = gw.engine.lifelong
        assert run is not None
        port = await gw.listen()
        print(port, flush=True)
        while run.status == "loaded":
            await asyncio.sleep(0.01)
        cpu0 = time.process_time()
        while gw.engine.now_ms() < seconds * 1000.0:
            await asyncio.sleep(0.05)
        stopped: asyncio.Future[tuple[int, float]] = asyncio.get_running_loop().create_future()

        def stop() -> None:  # in the owner task: the count and the time of the stop
            stopped.set_result((run.executor.finished_tasks, run.executor.now_ms))
            run.stop()

        gw.engine.queue.put_nowait(OwnerCall(stop))
        finished, at_ms = await stopped
        cpu = time.process_time() - cpu0
        await asyncio.wait_for(gw.wait_done(), 120.0)
        lat = sorted(gw.latencies_ms)
        planner = sorted(run.planner_ms)
        return {"finished": finished, "elapsed_ms": at_ms, "cpu_s": cpu,
                "segments": run.executor.segments, "triggers": run.executor.triggers,
                "planner_p50_ms": planner[len(planner) // 2] if planner else None,
                "planner_max_ms": planner[-1] if planner else None,
                "gateway_p99_ms": lat[int(0.99 * (len(lat) - 1))] if lat else None}


def serve_shift_main(args: argparse.Namespace) -> None:
    """``--serve-lifelong TRACE``: run the shift; print the port, then a JSON line."""
    _raise_fd_limit()
    # the event loop's thread only: the planner's own CPU is not the loop's
    profiler = cProfile.Profile(time.thread_time) if args.profile is not None else None
    if profiler is not None:
        profiler.enable()
    result = asyncio.run(_serve_shift(args.robots, args.seed, args.seconds,
                                      args.serve_lifelong, args.lookahead, args.window,
                                      args.vda_broker))
    if profiler is not None:
        profiler.disable()
        profiler.dump_stats(str(args.profile))
    print(json.dumps(result), flush=True)


def unlocked_by_finish(records: list[dict[str, Any]]
                       ) -> list[tuple[tuple[int, int], tuple[int, int]]]:
    """``((robot, action) finished, (robot, action) dispatched)`` for every dispatch the
    gateway made while handling a finish (the trace has it right after that finish)."""
    out = []
    last: tuple[int, int] | None = None
    for rec in records:
        kind = rec.get("type")
        if kind == "finish":
            last = (int(rec["robot"]), int(rec["action"]))
        elif kind == "dispatch":
            if last is not None:
                out.append((last, (int(rec["robot"]), int(rec["action"]))))
        else:
            last = None
    return out


async def _drive_shift(port: int, robots: int, jitter: float, wms: Wms,
                       result: subprocess.Popen[str]) -> FleetStats:
    """Fill the gateway's task pool through the task API, then run the fleet (the shift
    starts once every robot is there) and the WMS until the gateway process prints its result
    (the shift is over)."""
    await wms.fill()
    wms.stats.post_ms.clear()  # the initial fill is not the shift's
    feeding = asyncio.get_running_loop().create_task(wms.run(), name="wms")
    try:
        async with _connected_fleet(port, robots, jitter) as fleet:
            assert result.stdout is not None
            line = await asyncio.get_running_loop().run_in_executor(None,
                                                                    result.stdout.readline)
            fleet.stats.errors.extend([] if line else ["the gateway process printed no result"])
            _SHIFT_RESULT.append(line)
    finally:
        feeding.cancel()
        with contextlib.suppress(asyncio.CancelledError):
            await feeding  # a WMS error (a refused POST) is raised here
    return fleet.stats


_SHIFT_RESULT: list[str] = []


async def _drive_vda_shift(vehicles: list[VdaVehicle], broker: str, wms: Wms,
                           result: subprocess.Popen[str]) -> None:
    """As :func:`_drive_shift`, with simulated VDA 5050 vehicles on ``broker`` as the fleet."""
    await wms.fill()
    wms.stats.post_ms.clear()
    loop = asyncio.get_running_loop()
    stop = asyncio.Event()
    feeding = loop.create_task(wms.run(), name="wms")
    driving = loop.create_task(run_fleet(vehicles, BrokerConfig(url=broker), stop))
    try:
        assert result.stdout is not None
        line = await loop.run_in_executor(None, result.stdout.readline)
        _SHIFT_RESULT.append(line)
    finally:
        stop.set()
        await driving
        feeding.cancel()
        with contextlib.suppress(asyncio.CancelledError):
            await feeding


def run_shift(robots: int, seconds: int, seed: int, jitter: float, lookahead: int,
              window: int, profile: Path | None = None, vda5050: bool = False,
              tree: Path | None = None, reference: bool = True) -> dict[str, Any]:
    """One lifelong network run fed through the task API, and (``reference``) its
    virtual-time baseline; the measurements as a dict. ``vda5050``: the fleet is simulated
    VDA 5050 vehicles on a private mosquitto (picks and drops take no time, as in the
    virtual-time reference). ``tree``: the gateway process is that checkout's (as in
    :func:`run_once`)."""
    problem = shift_problem(robots, seed)
    reveal = shift_reveal(problem)
    with tempfile.TemporaryDirectory() as tmp, contextlib.ExitStack() as stack:
        broker = stack.enter_context(LocalBroker()) if vda5050 else None
        trace = Path(tmp) / "trace.jsonl"
        cmd = [sys.executable, str(tree / "bench" / "load.py") if tree else __file__,
               "--serve-lifelong", str(trace), "--robots",
               str(robots), "--seed", str(seed), "--seconds", str(seconds), "--lookahead",
               str(lookahead), "--window", str(window)]
        if profile is not None:
            cmd += ["--profile", str(profile)]
        if broker is not None:
            cmd += ["--vda-broker", broker]
        env = {**os.environ, "PYTHONPATH": str(tree)} if tree else None
        # in the tree: its planner process (``python -m``) imports from its working directory
        vehicles: list[VdaVehicle] = []
        stats = FleetStats()
        with children.running(cmd, stdout=subprocess.PIPE, text=True, env=env, cwd=tree) as gw:
            assert gw.stdout is not None
            port = int(gw.stdout.readline())
            _SHIFT_RESULT.clear()
            wms = Wms(port, TokensConfig().operators[0],
                      [tuple(problem.grid.cell(c) for c in t) for t in problem.tasks],
                      keep=reveal, lead=max(8, reveal // 20))
            if broker is None:
                stats = asyncio.run(_drive_shift(port, robots, jitter, wms, gw))
            else:
                config = shift_config(robots, seed, None, lookahead, window, broker)
                assert config.vda5050 is not None
                vehicles = make_vehicles(config.vda5050, World(), starts=shift_starts(config),
                                         jitter=jitter, seed=seed, action_s=0.0)
                asyncio.run(_drive_vda_shift(vehicles, broker, wms, gw))
            gw.wait(timeout=60)
        gateway = json.loads(_SHIFT_RESULT[0]) if _SHIFT_RESULT and _SHIFT_RESULT[0] else {}
        records = read_trace(trace)
    report = check_trace(records)
    dispatched = {(int(r["robot"]), int(r["action"])) for r in records
                  if r["type"] == "dispatch"}
    lat: list[float] = []
    if vda5050:  # what the vehicles drove: every dispatched action once
        driven = Counter((v.who, n) for v in vehicles for n in driven_actions(v))
        received = set(driven)
        duplicated = sum(n - 1 for n in driven.values())
        collisions = len(report.collisions) + len(vehicles[0].world.collisions
                                                  if vehicles and vehicles[0].world else [])
        picks = sum(len(v.node_actions_run) for v in vehicles)
        lost = len({(r, a) for r, a in dispatched} - received)
    else:
        got = {parse_action_id(a)[1:] for a in stats.received}
        lat = traced_latencies_ms(records, stats)
        duplicated = stats.duplicates + len(stats.received) - len(got)
        collisions, picks = len(report.collisions), 0
        lost = len(dispatched - set(got))
    t0 = time.process_time()
    virtual = run_lifelong(LifelongConfig(problem, ticks=seconds, period=1, tick_ms=1000.0,
                                          seed=seed, window=window, lanes=0,
                                          doors=0)
                           ) if reference else None  # no lanes nor doors: the gateway's
    # planner has none
    virtual_cpu = time.process_time() - t0
    minutes = gateway.get("elapsed_ms", 0.0) / 60_000.0
    network_rate = gateway.get("finished", 0) / minutes if minutes else 0.0
    virtual_rate = virtual.finished / (seconds / 60.0) if virtual is not None else 0.0
    actions = len(dispatched) if vda5050 else len(stats.received)
    return {"robots": robots, "seconds": seconds, "lookahead": lookahead,
            "window": window or 1, "jitter": jitter, "vda5050": vda5050,
            "tasks_network": gateway.get("finished"),
            "tasks_per_min_network": round(network_rate, 1),
            "tasks_virtual": virtual.finished if virtual is not None else None,
            "tasks_per_min_virtual": round(virtual_rate, 1) if virtual is not None else None,
            "throughput_ratio": round(network_rate / virtual_rate, 3) if virtual_rate else None,
            "actions": actions,
            "gateway_cpu_ms_per_action": round(1000.0 * gateway["cpu_s"] / actions, 4)
            if actions and "cpu_s" in gateway else None,
            "p50_ms": round(statistics.median(lat), 3) if lat else None,
            "p99_ms": round(_percentile(lat, 0.99), 3) if lat else None,
            "lost": lost, "duplicated": duplicated, "picks_and_drops": picks,
            "errors": len(stats.errors) + sum(len(v.errors) for v in vehicles),
            "collisions": collisions, "trace_errors": len(report.errors),
            "gateway_p99_ms": gateway.get("gateway_p99_ms"),
            "gateway_cpu_s": round(gateway.get("cpu_s", 0.0), 1),
            "segments": gateway.get("segments"), "slack_triggers": gateway.get("triggers"),
            "planner_p50_ms": gateway.get("planner_p50_ms"),
            "planner_max_ms": gateway.get("planner_max_ms"),
            "virtual_cpu_s": round(virtual_cpu, 1), "reveal": reveal,
            "task_posts": len(wms.stats.post_ms),
            "task_api_p50_ms": round(statistics.median(wms.stats.post_ms), 3)
            if wms.stats.post_ms else None,
            "task_api_p99_ms": round(_percentile(wms.stats.post_ms, 0.99), 3)
            if wms.stats.post_ms else None,
            "wms_submitted": wms.stats.submitted, "wms_min_lead": wms.stats.min_lead,
            "cpu_pressure_pct": cpu_pressure(), "load_1min": round(os.getloadavg()[0], 1)}


def journal_cost(robots: int, seconds: int, seed: int, jitter: float, lookahead: int,
                 profile: Path | None, pairs: int, generators: int = -1,
                 protocol: int = PROTOCOL_VERSION) -> dict[str, Any]:
    """``pairs`` runs without and with the journal, interleaved (ABBA: a trend in the
    machine's load charges neither side); the median journaled run's measurements, plus
    ``p99_journal_ratio`` (median p99 with / without) and the same for the gateway's own
    p99 and its CPU per action."""
    plain, journaled = interleaved(pairs, lambda journal: run_once(
        robots, seconds, seed, jitter, lookahead, profile if journal else None, journal,
        generators=generators, protocol=protocol))

    def ratio(key: str) -> float | None:
        return median_ratio(key, journaled, plain)

    result = sorted(journaled, key=lambda r: r["p99_ms"] or math.inf)[(pairs - 1) // 2]
    return {**result, "pairs": pairs,
            "p99_plain_ms": [r["p99_ms"] for r in plain],
            "p99_journal_ms": [r["p99_ms"] for r in journaled],
            "p99_journal_ratio": ratio("p99_ms"),
            "gateway_p99_journal_ratio": ratio("gateway_p99_ms"),
            "cpu_per_action_journal_ratio": ratio("gateway_cpu_ms_per_action"),
            "owner_cpu_journal_ratio": ratio("owner_cpu_ms_per_action"),
            "owner_cpu_ms_per_action_plain": [r["owner_cpu_ms_per_action"] for r in plain],
            "owner_cpu_ms_per_action_journal": [r["owner_cpu_ms_per_action"]
                                                for r in journaled]}


def interleaved(pairs: int, run: Callable[[bool], dict[str, Any]]
                ) -> tuple[list[dict[str, Any]], list[dict[str, Any]]]:
    """``pairs`` runs of ``run(False)`` and ``run(True)``, interleaved ABBA (a trend in the
    machine's load charges neither side), each result also printed to stderr; both lists."""
    runs: dict[bool, list[dict[str, Any]]] = {False: [], True: []}
    for i in range(pairs):
        for side in ((False, True) if i % 2 == 0 else (True, False)):
            res = run(side)
            print(json.dumps(res), file=sys.stderr, flush=True)
            runs[side].append(res)
    return runs[False], runs[True]


def median_ratio(key: str, these: list[dict[str, Any]], those: list[dict[str, Any]]
                 ) -> float | None:
    """Median of ``key`` over ``these`` / its median over ``those`` (None if unmeasured)."""
    num = [r[key] for r in these if r[key] is not None]
    den = [r[key] for r in those if r[key] is not None]
    if not num or not den or not statistics.median(den):
        return None
    return round(statistics.median(num) / statistics.median(den), 3)


def against_cost(robots: int, seconds: int, seed: int, jitter: float, lookahead: int,
                 pairs: int, tree: Path, journal: bool = False, generators: int = -1,
                 workers: int = 0, protocol: int = PROTOCOL_VERSION) -> dict[str, Any]:
    """``pairs`` runs of this gateway and of the one in ``tree`` (another version's checkout),
    interleaved ABBA, the same plan and this version's robots: the median run of this version
    (by CPU per action) plus ``cpu_per_action_ratio`` = median gateway CPU per action of this
    version / that of ``tree`` (< 1: this one is leaner), the same for p99, and the load
    average after each run; with ``journal`` both sides journal (each its own way); with
    ``workers`` both sides run that many worker processes, and the owner process's and the
    workers' CPU per action get ratios of their own. This version's robots speak
    ``protocol`` to this gateway and the newest version ``tree`` serves, if older, to that
    one."""
    theirs_speak = min(protocol, newest_version(tree))
    ours, theirs = interleaved(pairs, lambda other: run_once(
        robots, seconds, seed, jitter, lookahead, journal=journal,
        tree=tree if other else None, generators=generators, workers=workers,
        protocol=theirs_speak if other else protocol))
    key = "gateway_cpu_ms_per_action"
    result = sorted(ours, key=lambda r: r[key])[(pairs - 1) // 2]
    split: dict[str, Any] = {}
    for part in ("owner_process", "workers"):
        name = f"{part}_cpu_ms_per_action"
        split |= ({f"{part}_cpu_per_action_ratio": median_ratio(name, ours, theirs),
                   f"{name}_runs": [r[name] for r in ours],
                   f"against_{name}": [r[name] for r in theirs]} if workers else {})
    return {**result, **split, "pairs": pairs, "against": str(tree),
            "against_protocol": theirs_speak,
            "cpu_ms_per_action": [r[key] for r in ours],
            "against_cpu_ms_per_action": [r[key] for r in theirs],
            "load_1min_runs": [r["load_1min"] for r in ours],
            "against_load_1min_runs": [r["load_1min"] for r in theirs],
            "cpu_per_action_ratio": median_ratio(key, ours, theirs),
            "owner_cpu_per_action_ratio": median_ratio("owner_cpu_ms_per_action", ours, theirs),
            "owner_cpu_ms_per_action_runs": [r["owner_cpu_ms_per_action"] for r in ours],
            "against_owner_cpu_ms_per_action": [r.get("owner_cpu_ms_per_action") for r in theirs],
            "p99_against_ratio": median_ratio("p99_ms", ours, theirs)}


def shift_against(robots: int, seconds: int, seed: int, jitter: float, lookahead: int,
                  window: int, pairs: int, tree: Path) -> dict[str, Any]:
    """``pairs`` lifelong shifts of this gateway and of the one in ``tree``, interleaved ABBA
    (the same problem, task feed and robots, this version's): the median run of this version
    (by gateway CPU per action, the planner process's excluded on both sides) plus
    ``cpu_per_action_ratio`` (this / that: < 1 is leaner), the same for p99 and for tasks
    per minute, and the load average after each run. No virtual-time reference is run."""
    ours, theirs = interleaved(pairs, lambda other: run_shift(
        robots, seconds, seed, jitter, lookahead, window, tree=tree if other else None,
        reference=False))
    key = "gateway_cpu_ms_per_action"
    result = sorted(ours, key=lambda r: r[key] or math.inf)[(pairs - 1) // 2]
    return {**result, "pairs": pairs, "against": str(tree),
            "cpu_ms_per_action": [r[key] for r in ours],
            "against_cpu_ms_per_action": [r[key] for r in theirs],
            "tasks_per_min": [r["tasks_per_min_network"] for r in ours],
            "against_tasks_per_min": [r["tasks_per_min_network"] for r in theirs],
            "load_1min_runs": [r["load_1min"] for r in ours],
            "against_load_1min_runs": [r["load_1min"] for r in theirs],
            "cpu_per_action_ratio": median_ratio(key, ours, theirs),
            "p99_against_ratio": median_ratio("p99_ms", ours, theirs),
            "tasks_per_min_against_ratio": median_ratio("tasks_per_min_network", ours,
                                                        theirs)}


def uvloop_cost(robots: int, seconds: int, seed: int, jitter: float, lookahead: int,
                pairs: int, journal: bool, generators: int,
                protocol: int = PROTOCOL_VERSION) -> dict[str, Any]:
    """``pairs`` runs of the gateway on asyncio's own event loop and on uvloop's, interleaved
    ABBA: the median uvloop run plus ``uvloop_cpu_per_action_ratio`` (median gateway CPU per
    action, uvloop / asyncio: < 1 is leaner) and the same for the owner and for p99."""
    plain, fast = interleaved(pairs, lambda uv: run_once(
        robots, seconds, seed, jitter, lookahead, journal=journal, generators=generators,
        uvloop=uv, protocol=protocol))
    key = "gateway_cpu_ms_per_action"
    result = sorted(fast, key=lambda r: r[key])[(pairs - 1) // 2]
    return {**result, "pairs": pairs,
            "uvloop_cpu_per_action_ratio": median_ratio(key, fast, plain),
            "uvloop_owner_cpu_ratio": median_ratio("owner_cpu_ms_per_action", fast, plain),
            "uvloop_p99_ratio": median_ratio("p99_ms", fast, plain),
            "load_1min_runs": [r["load_1min"] for r in fast],
            "asyncio_load_1min_runs": [r["load_1min"] for r in plain]}


def workers_cost(robots: int, seconds: int, seed: int, jitter: float, lookahead: int,
                 pairs: int, workers: int, journal: bool, generators: int,
                 protocol: int = PROTOCOL_VERSION) -> dict[str, Any]:
    """``pairs`` runs of the gateway in one process and with ``workers`` worker processes,
    interleaved ABBA: the median run with workers plus, with workers / without (the median of
    each side), ``workers_cpu_per_action_ratio`` (the whole gateway's: > 1 costs more),
    ``workers_owner_process_cpu_ratio`` (the owner process's against the one process's),
    ``workers_p99_ratio`` and ``workers_rate_ratio`` (served actions per second)."""
    one, split = interleaved(pairs, lambda w: run_once(
        robots, seconds, seed, jitter, lookahead, journal=journal, generators=generators,
        workers=workers if w else 0, protocol=protocol))
    for r in one:  # one process: the owner process is the whole gateway
        r["owner_process_cpu_ms_per_action"] = r["gateway_cpu_ms_per_action"]
    key = "gateway_cpu_ms_per_action"
    result = sorted(split, key=lambda r: r[key])[(pairs - 1) // 2]
    return {**result, "pairs": pairs,
            "workers_cpu_per_action_ratio": median_ratio(key, split, one),
            "workers_owner_process_cpu_ratio": median_ratio("owner_process_cpu_ms_per_action",
                                                            split, one),
            "workers_p99_ratio": median_ratio("p99_ms", split, one),
            "workers_rate_ratio": median_ratio("achieved_per_s", split, one),
            "p99_ms_runs": [r["p99_ms"] for r in split],
            "one_process_p99_ms_runs": [r["p99_ms"] for r in one],
            "achieved_per_s_runs": [r["achieved_per_s"] for r in split],
            "one_process_achieved_per_s_runs": [r["achieved_per_s"] for r in one],
            "load_1min_runs": [r["load_1min"] for r in split],
            "one_process_load_1min_runs": [r["load_1min"] for r in one]}


def holds(result: dict[str, Any]) -> bool:
    """p99 within the limit, nothing lost or duplicated."""
    p99 = result["p99_ms"]
    return (p99 is not None and p99 <= P99_LIMIT_MS and result["lost"] == 0
            and result["duplicated"] == 0 and result["errors"] == 0)


def find_max(seconds: int, seed: int, jitter: float, lookahead: int, start: int, limit: int,
             generators: int = -1, workers: int = 0, protocol: int = PROTOCOL_VERSION
             ) -> tuple[int, list[dict[str, Any]]]:
    """Largest fleet (to within 10 %) that holds: double from ``start``, then bisect."""
    runs: list[dict[str, Any]] = []
    good, bad = 0, None
    r = start
    while r <= limit:
        res = run_once(r, seconds, seed, jitter, lookahead, generators=generators,
                       workers=workers, protocol=protocol)
        runs.append(res)
        print(json.dumps(res), file=sys.stderr, flush=True)
        if not holds(res):
            bad = r
            break
        good, r = r, r * 2
    while bad is not None and bad - good > max(50, good // 10):
        mid = (good + bad) // 2
        res = run_once(mid, seconds, seed, jitter, lookahead, generators=generators,
                       workers=workers, protocol=protocol)
        runs.append(res)
        print(json.dumps(res), file=sys.stderr, flush=True)
        if holds(res):
            good = mid
        else:
            bad = mid
    return good, runs


def main() -> int:
    """Parse arguments and run."""
    p = CommandParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--robots", type=int, default=500)
    p.add_argument("--seconds", type=int, default=30, help="plan steps (~ run seconds)")
    p.add_argument("--seed", type=int, default=1)
    p.add_argument("--jitter", type=float, default=0.2,
                   help="actions last 1000 ms x U(1-J, 1+J) (default 0.2; 0 = lockstep)")
    p.add_argument("--json", action="store_true", help="print the result as one JSON line")
    p.add_argument("--find-max", action="store_true",
                   help="search the largest fleet with p99 <= 50 ms, 0 lost, 0 duplicated")
    p.add_argument("--max-robots", type=int, default=4000, help="upper bound of --find-max")
    p.add_argument("--protocol", type=int, choices=[2, 3], default=PROTOCOL_VERSION,
                   help="the protocol version the lean robots speak (default %(default)s: no "
                        "ack; 2: an ack per action); with --against, the other side's robots "
                        "speak the newest version it serves, if older")
    p.add_argument("--lookahead", type=int, default=0,
                   help="the gateway's dispatch_lookahead (default 0: classic dispatch, so that "
                   "every dispatch after the first is unlocked by a finish and measured)")
    p.add_argument("--profile", type=Path, help="cProfile the gateway process into this file")
    p.add_argument("--journal", action="store_true",
                   help="the journal's cost: runs without and with the journal (SQLite WAL in "
                        "a temporary directory, as fleetgate serve does by default), "
                        "interleaved, and prints p99_journal_ratio; the baseline run is "
                        "journaled")
    p.add_argument("--pairs", type=int, default=1,
                   help="with --journal, --against or --workers (--lifelong too): how many runs "
                        "of each (default 1)")
    p.add_argument("--against", type=Path, metavar="DIR",
                   help="also run the gateway of another version's checkout DIR (e.g. `git "
                        "worktree add DIR 1045d02`), interleaved with this one, and print "
                        "cpu_per_action_ratio (this / that, median over --pairs)")
    p.add_argument("--lifelong", action="store_true",
                   help="a warehouse shift (lifelong mode) for --seconds of plan time: "
                        "throughput against virtual time, p99, lost, duplicated")
    p.add_argument("--vda5050", action="store_true",
                   help="--lifelong: the fleet is simulated VDA 5050 vehicles on a private "
                        "mosquitto, driven by the gateway's master control (lost and "
                        "duplicated from the edges they drove; no robot-side p99)")
    p.add_argument("--vda-broker", help=argparse.SUPPRESS)
    p.add_argument("--window", type=int, default=0,
                   help="--lifelong: timesteps planned per call (default 0: one period)")
    p.add_argument("--generators", type=int, default=-1, metavar="N",
                   help="robots in N lean generator processes (raw websocket frames; default: "
                        "one per 2,500 robots, at most 4); 0: the full simulated robots of "
                        "sim_clients.fleet in this process")
    p.add_argument("--uvloop", action="store_true",
                   help="the gateway on uvloop's event loop (pip install uvloop) and on "
                        "asyncio's, interleaved (--pairs): uvloop_cpu_per_action_ratio")
    p.add_argument("--workers", type=int, default=0, metavar="N",
                   help="one run, --pairs, --against (both sides) or --find-max: the gateway "
                        "with N worker processes serving the robots' websockets (its config's "
                        "workers; default 0: one process); gateway_cpu_ms_per_action then "
                        "counts them too")
    p.add_argument("--serve-workers", type=int, default=0, help=argparse.SUPPRESS)
    p.add_argument("--serve", type=Path, help=argparse.SUPPRESS)
    p.add_argument("--serve-uvloop", action="store_true", help=argparse.SUPPRESS)
    p.add_argument("--serve-trace", type=Path, help=argparse.SUPPRESS)
    p.add_argument("--trace", action="store_true",
                   help="one run: the gateway writes its trace and tracecheck checks it "
                        "(trace_errors, collisions)")
    p.add_argument("--journaled", action="store_true",
                   help="one run: with the journal on (no run without it)")
    p.add_argument("--lean-part", help=argparse.SUPPRESS)
    p.add_argument("--lean-files", nargs=2, type=Path, help=argparse.SUPPRESS)
    p.add_argument("--port", type=int, help=argparse.SUPPRESS)
    p.add_argument("--serve-lifelong", type=Path, help=argparse.SUPPRESS)
    p.add_argument("--serve-journal", type=Path, help=argparse.SUPPRESS)
    args = p.parse_args()
    if args.serve is not None:
        serve_main(args.serve, args.profile, args.lookahead, args.serve_journal,
                   args.serve_uvloop, args.serve_trace, args.serve_workers)
        return 0
    if args.lean_part is not None:
        lean_main(args)
        return 0
    if args.serve_lifelong is not None:
        serve_shift_main(args)
        return 0
    _raise_fd_limit()
    if args.lookahead < 0:
        p.error("--lookahead must be >= 0")
    if args.pairs < 1:
        p.error("--pairs must be >= 1")
    if args.against is not None and not (args.against / "bench" / "load.py").is_file():
        p.error(f"--against {args.against}: no bench/load.py there (give a checkout of "
                "fleetgate)")
    if args.against is not None and (args.find_max or args.vda5050):
        p.error("--against measures one run per side over websockets: not with --find-max "
                "or --vda5050")
    if args.uvloop and (args.against or args.find_max or args.lifelong):
        p.error("--uvloop measures one run per loop: not with --against, --find-max or "
                "--lifelong")
    if args.uvloop and importlib.util.find_spec("uvloop") is None:
        p.error("--uvloop: uvloop is not installed (pip install uvloop)")
    if (args.trace or args.journaled) and (args.against or args.journal or args.uvloop
                                           or args.find_max or args.lifelong):
        p.error("--trace and --journaled are for one run: not with --against, --journal, "
                "--uvloop, --find-max or --lifelong")
    if args.workers < 0:
        p.error("--workers must be >= 0")
    if args.workers and ((args.journal and args.against is None) or args.uvloop
                         or args.lifelong):
        p.error("--workers is for one run, --pairs, --against or --find-max: not with "
                "--journal (but with --against --journal), --uvloop or --lifelong")
    if args.profile is not None:
        check_writable(args.profile)  # the gateway writes it at the end of the run
    if args.vda5050 and not args.lifelong:
        p.error("--vda5050 measures a lifelong shift: give --lifelong too")
    if args.lifelong and args.against is not None:
        shift = shift_against(args.robots, args.seconds, args.seed, args.jitter,
                              args.lookahead, args.window, args.pairs, args.against.resolve())
        print(json.dumps(shift) if args.json else
              f"lifelong: {shift['robots']} robots, {args.seconds} s, {args.pairs} pair(s) "
              f"against {shift['against']}: cpu_per_action_ratio "
              f"{shift['cpu_per_action_ratio']} ({shift['cpu_ms_per_action']} vs "
              f"{shift['against_cpu_ms_per_action']} ms per action), tasks/min ratio "
              f"{shift['tasks_per_min_against_ratio']}, p99 ratio "
              f"{shift['p99_against_ratio']}; lost {shift['lost']}, duplicated "
              f"{shift['duplicated']}, collisions {shift['collisions']}")
        return 0
    if args.lifelong:
        shift = run_shift(args.robots, args.seconds, args.seed, args.jitter, args.lookahead,
                          args.window, args.profile, args.vda5050)
        print(json.dumps(shift) if args.json else
              f"lifelong: {shift['robots']} robots, {args.seconds} s: "
              f"{shift['tasks_per_min_network']} tasks/min over the network vs "
              f"{shift['tasks_per_min_virtual']} in virtual time = throughput_ratio "
              f"{shift['throughput_ratio']}; p99 {shift['p99_ms']} ms; lost {shift['lost']}, "
              f"duplicated {shift['duplicated']}, collisions {shift['collisions']}; POST "
              f"/tasks p99 {shift['task_api_p99_ms']} ms")
        _print_profile(args.profile)
        return 0
    gens = args.generators
    baseline = run_once(BASELINE_ROBOTS, min(args.seconds, 10), args.seed, args.jitter,
                        args.lookahead, journal=args.journal or args.journaled,
                        generators=gens, workers=args.workers, protocol=args.protocol)
    if args.find_max:
        best, runs = find_max(args.seconds, args.seed, args.jitter, args.lookahead, 250,
                              args.max_robots, gens, args.workers, args.protocol)
        result = next((r for r in runs if r["robots"] == best), baseline)
        result = {"max_robots": best, **result}
    elif args.against is not None:
        result = against_cost(args.robots, args.seconds, args.seed, args.jitter,
                              args.lookahead, args.pairs, args.against.resolve(),
                              args.journal, gens, args.workers, args.protocol)
    elif args.workers and args.pairs > 1:
        result = workers_cost(args.robots, args.seconds, args.seed, args.jitter,
                              args.lookahead, args.pairs, args.workers, args.journaled, gens,
                              args.protocol)
    elif args.uvloop:
        result = uvloop_cost(args.robots, args.seconds, args.seed, args.jitter, args.lookahead,
                             args.pairs, args.journal, gens, args.protocol)
    elif args.journal:
        result = journal_cost(args.robots, args.seconds, args.seed, args.jitter,
                              args.lookahead, args.profile, args.pairs, gens, args.protocol)
    else:
        result = run_once(args.robots, args.seconds, args.seed, args.jitter, args.lookahead,
                          args.profile, journal=args.journaled, generators=gens,
                          trace=args.trace, workers=args.workers, protocol=args.protocol)
    base_p99 = baseline["p99_ms"]
    result["baseline_robots"] = BASELINE_ROBOTS
    result["baseline_p99_ms"] = base_p99
    result["p99_ratio"] = (round(result["p99_ms"] / base_p99, 2)
                           if result.get("p99_ms") and base_p99 else None)
    if args.json:
        print(json.dumps(result))
    else:
        print(f"{result['robots']} robots, {result['actions']} actions: p50 "
              f"{result['p50_ms']} ms, p99 {result['p99_ms']} ms ({result['p99_ratio']}x the "
              f"{BASELINE_ROBOTS}-robot p99), lost {result['lost']}, duplicated "
              f"{result['duplicated']}, achieved/offered rate {result['rate_ratio']}; gateway "
              f"dispatch lookahead {args.lookahead}"
              + (" (0 = classic dispatch: every latency is finish -> the dispatch it unlocks)"
                 if args.lookahead == 0 else
                 " (Type 1 unlocks happen before the finish: latencies are not comparable)"))
    _print_profile(args.profile)
    return 0


def _print_profile(profile: Path | None) -> None:
    if profile is not None and profile.exists():
        pstats.Stats(str(profile), stream=sys.stderr).sort_stats("tottime").print_stats(25)


if __name__ == "__main__":
    run_main("bench/load.py", main)
