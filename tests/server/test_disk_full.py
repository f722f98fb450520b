"""Disk full (issue 26, defect 1): ``fleetgate serve`` in lifelong mode whose files cannot
grow beyond a limit (``RLIMIT_FSIZE``: the write fails at the lowest layer, as on a full
disk) takes task batches through the task API until the journal cannot be written. The
process then logs one line and exits non-zero (no listening zombie); every batch answered 201
is in the journal after a restart (its key answers 200 with the same ids), and the batch that
got no answer reuses no acknowledged id when retried: created anew (201) if its own commit
failed, or found (200) if it was committed and the process stopped on a later commit before
its answer left (acknowledged means durable; durable need not mean acknowledged: at load 37
that was the case in 3 runs of 3)."""

from __future__ import annotations

import asyncio
import json
from pathlib import Path
from typing import Any

from bench.crash import GatewayProcess, free_port
from gateway.planning.lorr import warehouse_problem
from gateway.runtime.exits import EXIT_JOURNAL
from tests.server.task_client import call

ROBOTS = 4


def test_a_full_disk_stops_the_gateway_and_loses_nothing_acknowledged(tmp_path: Path) -> None:
    port = free_port()
    gw = GatewayProcess(tmp_path, port, speed=10.0, policy="none")
    config = {**json.loads(gw.config.read_text()), "map": None, "trace": None,
              "lifelong": {"robots": ROBOTS, "warehouse": [2, 3], "task_list": False}}
    gw.config.write_text(json.dumps(config))
    grid = warehouse_problem(ROBOTS, 0, (2, 3), p_delay=0.0).grid
    free = [[x, y] for x, y in grid.free_cells()]
    acked: dict[str, list[int]] = {}
    out: dict[str, Any] = {}

    def batch(n: int) -> dict[str, Any]:
        return {"tasks": [{"errands": [free[(7 * k + n) % len(free)],
                                       free[(13 * k + 5) % len(free)]]} for k in range(200)],
                "idempotency_key": f"batch-{n}"}

    async def main() -> None:
        gw.start(file_limit=600_000)
        n = 0
        for n in range(200):
            try:  # answered, or the connection ends with the process (a bound for a hang only:
                # a batch given up on while slowly committed would be retried with 200)
                reply = await asyncio.wait_for(call(port, "POST", "/tasks", batch(n)), 120)
            except (OSError, asyncio.IncompleteReadError):
                break
            assert reply.status == 201, reply.body
            acked[f"batch-{n}"] = [t["id"] for t in reply.json()["tasks"]]
        out["failed"] = n
        assert gw.proc is not None
        out["code"] = await asyncio.to_thread(gw.proc.wait, 120)
        gw.proc = None
        gw.start()  # no limit now
        for key, ids in acked.items():
            n_ = int(key.split("-")[1])
            retry = await call(port, "POST", "/tasks", batch(n_))
            assert (retry.status, [t["id"] for t in retry.json()["tasks"]]) == (200, ids), key
        again = await call(port, "POST", "/tasks", batch(out["failed"]))
        out["again"] = (again.status, [t["id"] for t in again.json()["tasks"]])

    try:
        asyncio.run(main())
    finally:
        gw.stop()
    assert len(acked) >= 2, "the limit was hit before anything was acknowledged"
    assert out["code"] == EXIT_JOURNAL
    log = gw.log_path.read_text()
    assert log.count("journal write failed") == 1 and "Traceback" not in log, log[-2000:]
    status, ids = out["again"]
    assert status in (200, 201) and ids
    taken = {i for v in acked.values() for i in v}
    assert not taken & set(ids)  # no acknowledged id is reused
