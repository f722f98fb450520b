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

Prints ONE line (``--json``: a JSON object with the keys above).

    .venv/bin/python bench/crash.py --kills 20 --seed 1 --json
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import json
import random
import socket
import sqlite3
import statistics
import subprocess
import sys
import tempfile
import time
import urllib.request
from collections import Counter
from pathlib import Path
from typing import Any

from gateway.planning.movingai import write_map
from gateway.planning.plan import Plan
from gateway.planning.random_plans import open_grid, random_plan
from gateway.server.clock import LoopClock
from protocol import LoadPlan, Ok, Start, decode, encode
from sim_clients.connect import websocket_connector
from sim_clients.fleet import SimFleet
from tracecheck import check_trace, read_trace

OPERATOR = "demo-operator"


def free_port() -> int:
    """A port that was free a moment ago (the gateway must keep one across restarts)."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


class GatewayProcess:
    """``python -m gateway serve`` with one fixed command line, killed and restarted."""

    def __init__(self, workdir: Path, port: int, speed: float, policy: str) -> None:
        self.port = port
        self.trace = workdir / "trace.jsonl"
        config = workdir / "gateway.json"
        config.write_text(json.dumps({"speed": speed, "policy": policy, "trace": str(self.trace),
                                      "ping_interval_s": 2.0, "ping_timeout_s": 2.0}))
        self.journal = workdir / "journal.sqlite"
        self.cmd = [sys.executable, "-m", "gateway", "serve", "--config", str(config),
                    "--journal", str(self.journal), "--port", str(port),
                    "--log-level", "WARNING"]
        self.log_path = workdir / "gateway.log"
        self.log = self.log_path.open("a")
        self.proc: subprocess.Popen[bytes] | None = None
        self.starts = 0
        self.down_s: list[float] = []
        """Wall time from each kill to the restarted gateway's readiness."""
        self._killed_at: float | None = None

    def start(self) -> None:
        """Start the process and wait until it answers ``/readyz``."""
        self.proc = subprocess.Popen(self.cmd, stdout=self.log, stderr=self.log)
        self.starts += 1
        deadline = time.monotonic() + 60.0
        while time.monotonic() < deadline:
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
        raise RuntimeError("the gateway did not become ready")

    def health(self) -> dict[str, Any]:
        """What ``/healthz`` says."""
        with urllib.request.urlopen(f"http://127.0.0.1:{self.port}/healthz", timeout=5) as r:
            return dict(json.loads(r.read()))

    def kill(self) -> None:
        """SIGKILL, and reap."""
        if self.proc is not None and self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait()
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

    def stop(self) -> None:
        """End the process for good."""
        if self.proc is not None and self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(timeout=10)
            except subprocess.TimeoutExpired:
                self.kill()
        self.proc = None
        self.log.close()


async def _operator(port: int, *commands: LoadPlan | Start) -> None:
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


async def _run(gw: GatewayProcess, map_file: Path, plan: Plan, speed: float,
               kills: list[float], rng: random.Random) -> dict[str, Any]:
    """One execution of ``plan``; the gateway is killed ``len(kills)`` times, at those
    delays (s) after the start or after the previous restart."""
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
    await fleet.start()
    try:
        await fleet.wait_connected(timeout=60.0)
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
        per_run: int, policy: str = "none") -> dict[str, Any]:
    """The baseline run, then disturbed runs until ``kills`` kills were made."""
    rng = random.Random(seed)
    plan = random_plan(open_grid(max(6, robots), max(6, robots)), robots, steps, rng)
    run_s = plan.makespan / speed
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        map_file = work / "open.map"
        write_map(open_grid(max(6, robots), max(6, robots)), map_file)
        gw = GatewayProcess(work, free_port(), speed, policy)
        try:
            gw.start()
            base = asyncio.run(_run(gw, map_file, plan, speed, [], rng))
            runs: list[dict[str, Any]] = []
            left = kills
            while left > 0:
                n = min(per_run, left)
                # kill points spread over the run: the first after U(0.1, 1) of a share
                delays = [rng.uniform(0.1, 1.0) * run_s / (n + 1) for _ in range(n)]
                runs.append(asyncio.run(_run(gw, map_file, plan, speed, delays, rng)))
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


def main() -> int:
    """Parse arguments and run."""
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
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
    p.add_argument("--json", action="store_true", help="print the result as one JSON line")
    args = p.parse_args()
    if args.kills < 0 or args.robots < 1 or args.steps < 1 or args.kills_per_run < 1:
        p.error("--kills >= 0, --robots, --steps and --kills-per-run >= 1")
    result = run(args.kills, args.seed, args.robots, args.steps, args.speed,
                 args.kills_per_run, args.policy)
    if args.json:
        print(json.dumps(result))
    else:
        print(f"{result['kills']} kills: {result['resumed']} resumed, {result['lost']} lost, "
              f"{result['duplicated']} duplicated, {result['collisions']} collisions; SOC "
              f"{result['soc_ratio']}x the undisturbed run's")
    return 0


if __name__ == "__main__":
    sys.exit(main())
