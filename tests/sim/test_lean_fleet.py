"""The lean load generator: its frames read back by websockets' own parser, and a lean fleet
executing a plan against a real gateway over websockets (every action once, no error, the
gateway's trace clean)."""

from __future__ import annotations

import asyncio
import random
from pathlib import Path

import pytest
from websockets.frames import Frame, Opcode
from websockets.streams import StreamReader

from gateway.planning.instance import Instance
from gateway.planning.random_plans import open_grid, random_plan
from gateway.server.config import GatewayConfig
from gateway.server.gateway import Gateway
from gateway.server.planner import Problem
from protocol import action_id
from sim_clients.lean_fleet import LeanFleet, frame
from tracecheck import check_trace, read_trace


@pytest.mark.parametrize("size", [0, 125, 126, 65535, 65536])
def test_frames_parse_as_masked_text_frames(size: int) -> None:
    text = "é" * (size // 2) + "x" * (size % 2)
    reader = StreamReader()
    reader.feed_data(frame(text))
    parser = Frame.parse(reader.read_exact, mask=True)
    with pytest.raises(StopIteration) as stop:
        next(parser)
    parsed: Frame = stop.value.value
    assert (parsed.opcode, parsed.fin, parsed.data.decode()) == (Opcode.TEXT, True, text)


def test_a_lean_fleet_executes_a_plan_over_websockets(tmp_path: Path) -> None:
    grid = open_grid(6, 6)
    plan = random_plan(grid, 5, 4, random.Random(3))
    inst = Instance(grid, tuple(p[0] for p in plan.paths), tuple(p[-1] for p in plan.paths),
                    "open")
    trace = tmp_path / "trace.jsonl"
    config = GatewayConfig(port=0, map=None, autostart=True, policy="none", action_ms=150.0,
                           state_period_ms=100.0, dispatch_lookahead=1, trace=trace,
                           log_level="WARNING")

    async def main() -> LeanFleet:
        async with Gateway(config) as gw:
            gw.engine.load(Problem(inst, "open", plan))
            port = await gw.listen()
            fleet = LeanFleet(port, {r: [list(c) for c in p] for r, p in enumerate(plan.paths)},
                              jitter=0.2, seed=1)
            await fleet.run(deadline_s=30.0)
            await asyncio.wait_for(gw.wait_done(), 10.0)
            return fleet

    fleet = asyncio.run(main())
    expected = {action_id(0, r, i) for r, p in enumerate(plan.paths) for i in range(len(p) - 1)}
    stats = fleet.stats
    assert stats.errors == []
    assert stats.duplicates == 0
    assert set(stats.received) == expected
    assert set(stats.finish_sent) == expected
    assert all(stats.finish_sent[a] > stats.received[a] for a in expected)
    report = check_trace(read_trace(trace))
    assert report.errors == [] and report.collisions == []
