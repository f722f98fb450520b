"""A power cut loses the journal's last records (issue 26, defects 2 and 9): the gateway stops
mid-run, the last 1-60 records (reports and ticks: what ``synchronous=NORMAL`` may lose) are
dropped from its journal while the robots keep what they did, and a new gateway resumes. With
robots that implement only the MUST rules (no repeated ``finished``), the run completes
(nothing stuck), every action is executed once, and the trace, cut back to the journal, is one
valid run."""

from __future__ import annotations

import asyncio
from collections import Counter
from pathlib import Path
from typing import Any

import pytest

from bench.faults import drop_tail
from gateway.server.gateway import Gateway
from tests.server.test_journal import running, workload
from tracecheck import check_trace, read_trace


@pytest.mark.parametrize(("k", "seed", "stop_s"), [(1, 1, 0.20), (5, 2, 0.15), (17, 3, 0.25),
                                                    (40, 4, 0.10), (60, 5, 0.20)])
def test_a_power_cut_resumes_with_must_only_robots(tmp_path: Path, k: int, seed: int,
                                                   stop_s: float) -> None:
    journal, trace = tmp_path / "journal.sqlite", tmp_path / "trace.jsonl"
    problem = workload(6, 10, seed)
    executed: Counter[tuple[int, int, int]] = Counter()
    done: dict[str, Any] = {}

    async def main() -> None:
        config, gw, port, fleet = await running(
            journal, trace, problem, must_only=True, on_event=lambda kind, p, r, i: executed.update(
                [(p, r, i)] if kind == "execute" else []))
        await asyncio.sleep(stop_s)
        await gw.stop()
        assert gw.engine.status == "running"
        done["dropped"] = drop_tail(journal, k)
        gw2 = Gateway(config.model_copy(update={"port": port}))
        await gw2.start()
        assert gw2.resumed
        await gw2.listen()
        done["summary"] = await asyncio.wait_for(gw2.wait_done(), 30)
        await fleet.stop()
        await gw2.stop()

    asyncio.run(main())
    assert done["dropped"] >= 1
    twice = [a for a, n in executed.items() if n > 1]
    assert twice == []
    records = read_trace(trace)
    report = check_trace(records)
    assert report.errors == [] and report.collisions == []
    finishes = [(r["plan"], r["robot"], r["action"]) for r in records if r["type"] == "finish"]
    assert len(finishes) == len(set(finishes)) == sum(len(p) - 1 for p in problem.plan.paths)
