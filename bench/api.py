"""The task API under load: ``POST /tasks`` round trips of ``--clients`` concurrent WMS clients
against ``fleetgate serve`` in lifelong mode (a child process, no robots: tasks stay queued),
as a ratio against another version measured in the same invocation.

Both gateways journal every change (each answered once committed), unless ``--no-journal``
(then what is left is the HTTP surface and the task pool). Each client submits one task per
request, each with its own ``Idempotency-Key``, on a new
connection each time (what a WMS without keep-alive does; both versions answer it), for
``--seconds``; the first second of each run is left out (connections warming up). ``--against
DIR`` is a checkout of the other version (``git worktree add DIR main``): its gateway runs
with ``DIR`` first on the Python path; ``--pairs N`` runs of each side, interleaved ABBA.
Prints ONE JSON line: this version's and that one's p50 and p99 (medians over the runs),
requests per second, the gateway process's CPU ms per request (``cpu_ms``: what a loaded,
shared machine disturbs least), any status but 201 counted as ``refused``, ``p99_ratio``,
``p50_ratio`` and ``cpu_ratio`` (this / that: < 1 is faster or leaner) and ``rps_ratio``
(> 1 is faster).

    .venv/bin/python bench/api.py --clients 50 --seconds 10 --against ../lead --pairs 2
"""

from __future__ import annotations

import fleetgate.userio.script  # noqa: F401 (first: Ctrl-C while importing is one line)

# isort: split

import asyncio
import itertools
import json
import os
import statistics
import tempfile
import time
from pathlib import Path
from typing import Any

from crash import GatewayProcess, cpu_s, free_port  # bench/crash.py

from fleetgate.userio.exits import CommandParser, run_main
from gateway.planning.lorr import warehouse_problem
from sim_clients.wms import http

TOKEN = "bench-operator"
WAREHOUSE = (2, 3)


def _percentile(values: list[float], q: float) -> float:
    ordered = sorted(values)
    return ordered[min(len(ordered) - 1, int(q * len(ordered)))]


async def _load(port: int, clients: int, seconds: float) -> dict[str, Any]:
    """``clients`` concurrent submitters for ``seconds``: round trips in ms (after the first
    second) and the statuses."""
    free = [list(c) for c in warehouse_problem(3, 0, WAREHOUSE, p_delay=0.0).grid.free_cells()]
    keys = itertools.count()
    start = time.perf_counter()
    times: list[float] = []
    statuses: dict[int, int] = {}

    async def client() -> None:
        while (now := time.perf_counter()) - start < seconds:
            k = next(keys)
            status, _ = await http(port, "POST", "/tasks", TOKEN,
                                   {"errands": [free[k % len(free)]]},
                                   {"Idempotency-Key": f"bench-{k}"})
            statuses[status] = statuses.get(status, 0) + 1
            if now - start >= 1.0:
                times.append((time.perf_counter() - now) * 1000.0)

    await asyncio.gather(*(client() for _ in range(clients)))
    return {"p50_ms": statistics.median(times), "p99_ms": _percentile(times, 0.99),
            "rps": len(times) / (seconds - 1.0), "requests": sum(statuses.values()),
            "refused": sum(n for s, n in statuses.items() if s != 201)}


def run_once(source: Path | None, clients: int, seconds: float, journal: bool = True
             ) -> dict[str, Any]:
    """One run against a fresh gateway of this version (``source`` None) or of ``source``
    (``journal`` False: serving with ``--no-journal``)."""
    with tempfile.TemporaryDirectory() as work:
        gw = GatewayProcess(Path(work), free_port(), speed=1.0, policy="none")
        gw.config.write_text(json.dumps({
            **json.loads(gw.config.read_text()), "map": None, "autostart": False,
            "tokens": {"operators": [TOKEN]}, "max_connections": 10000,
            "lifelong": {"robots": 3, "warehouse": list(WAREHOUSE), "task_list": False}}))
        if not journal:
            at = gw.cmd.index("--journal")
            gw.cmd[at:at + 2] = ["--no-journal"]
        if source is not None:  # its gateway first on the path
            gw.env = {**os.environ, "PYTHONPATH": str(source.resolve())}
            gw.cwd = source.resolve()
        gw.start()
        assert gw.proc is not None
        try:
            cpu0 = cpu_s(gw.proc.pid)
            run = asyncio.run(_load(gw.port, clients, seconds))
            run["cpu_ms"] = 1000.0 * (cpu_s(gw.proc.pid) - cpu0) / max(1, run["requests"])
            return run
        finally:
            gw.stop()


def main() -> int:
    """Parse the arguments, run, print one JSON line."""
    p = CommandParser(description=__doc__.splitlines()[0])
    p.add_argument("--clients", type=int, default=50)
    p.add_argument("--seconds", type=float, default=10.0)
    p.add_argument("--against", type=Path, metavar="DIR", required=True,
                   help="a checkout of the version to compare with")
    p.add_argument("--pairs", type=int, default=2)
    p.add_argument("--no-journal", action="store_true",
                   help="both gateways journal nothing: the HTTP surface and the task pool "
                        "alone, without the journal's commits")
    args = p.parse_args()
    if not (args.against / "gateway").is_dir():
        p.error(f"--against {args.against}: not a fleetgate checkout")
    these: list[dict[str, Any]] = []
    those: list[dict[str, Any]] = []
    for i in range(args.pairs):  # ABBA
        order = [None, args.against] if i % 2 == 0 else [args.against, None]
        for source in order:
            (these if source is None else those).append(
                run_once(source, args.clients, args.seconds, not args.no_journal))

    def median(runs: list[dict[str, Any]], key: str) -> float:
        return round(statistics.median(r[key] for r in runs), 3)

    result = {"clients": args.clients, "seconds": args.seconds, "pairs": args.pairs,
              "journal": not args.no_journal,
              **{f"{k}": median(these, k) for k in ("p50_ms", "p99_ms", "rps", "cpu_ms")},
              **{f"against_{k}": median(those, k)
                 for k in ("p50_ms", "p99_ms", "rps", "cpu_ms")},
              "refused": sum(r["refused"] for r in these),
              "against_refused": sum(r["refused"] for r in those)}
    result["p99_ratio"] = round(result["p99_ms"] / result["against_p99_ms"], 3)
    result["p50_ratio"] = round(result["p50_ms"] / result["against_p50_ms"], 3)
    result["rps_ratio"] = round(result["rps"] / result["against_rps"], 3)
    result["cpu_ratio"] = round(result["cpu_ms"] / result["against_cpu_ms"], 3)
    print(json.dumps(result))
    return 0


if __name__ == "__main__":
    run_main("bench/api.py", main)
