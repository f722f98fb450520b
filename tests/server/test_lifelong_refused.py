"""A robot refuses an action during a lifelong shift, over real websockets on 127.0.0.1: the
gateway takes it (and what it dispatched after it) back without an error and dispatches it
again at the next planning period; the shift goes on, nothing is lost or run twice, and the
independent trace checker accepts the trace. In virtual time (the planner charged 120 ms a
call), so the plans come when the shift's clock says, whatever the machine's load."""

from __future__ import annotations

import asyncio
from pathlib import Path

from gateway.server.clock import VirtualClock, run_virtual
from gateway.server.config import GatewayConfig, LifelongSettings
from gateway.server.gateway import Gateway
from protocol import Action
from protocol.robot_session import RobotSession
from sim_clients.connect import websocket_connector
from sim_clients.fleet import SimFleet
from sim_clients.shift import start_shift, stop_shift
from tracecheck import check_trace, read_trace

ROBOTS = 6
REFUSE_AT = 5
"""Robot 0's body refuses the 5th action it is sent, once."""


def test_a_refused_action_is_taken_back_and_run_later(tmp_path: Path) -> None:
    trace = tmp_path / "trace.jsonl"
    received: list[str] = []

    def flaky(action: Action) -> None:
        received.append(action.action_id)
        if len(received) == REFUSE_AT:
            raise ValueError("the lift is not down yet")

    def resent() -> bool:
        """The refused action was sent again, and one more after it."""
        return len(received) > REFUSE_AT and received.count(received[REFUSE_AT - 1]) == 2 \
            and received[-1] != received[REFUSE_AT - 1]

    async def main() -> tuple[object, list[str]]:
        config = GatewayConfig(
            port=0, map=None, autostart=True, speed=10.0, trace=trace, log_level="WARNING",
            lifelong=LifelongSettings(robots=ROBOTS, warehouse=(2, 3)))
        async with Gateway(config, clock=VirtualClock(solver_time=120.0)) as gw:
            port = await gw.listen()
            fleet = SimFleet(websocket_connector(f"ws://127.0.0.1:{port}/ws"), range(ROBOTS),
                             clock=gw.clock, send_state=False)
            fleet.add_robot(0).session = RobotSession(0, check=flaky)
            await start_shift(gw, fleet)
            async with asyncio.timeout(120.0):  # (virtual seconds)
                while gw.engine.now_ms() < 20_000.0 or not resent():
                    await asyncio.sleep(0.05)
            stats = await stop_shift(gw, fleet)
            await fleet.stop()
            return stats, list(fleet.stats.errors)

    stats, errors = run_virtual(main())
    refused = received[REFUSE_AT - 1]
    # the robot's own refusals, and no error from the gateway
    assert errors[0] == f"robot 0 refused {refused}: the lift is not down yet"
    assert all(e.startswith("robot 0 refused ") for e in errors), errors
    assert received.count(refused) == 2  # sent again, and taken then
    assert stats.lost == 0 and stats.duplicated == 0 and stats.collisions == 0
    records = read_trace(trace)
    report = check_trace(records)
    assert report.errors == [] and report.collisions == []
    index = int(refused.rsplit(".", 1)[1])
    kinds = [r["type"] for r in records if r.get("robot") == 0 and r.get("action") == index]
    assert kinds == ["dispatch", "refused", "dispatch", "start", "finish"]
    finishes = [(r["robot"], r["action"]) for r in records if r["type"] == "finish"]
    assert len(finishes) == len(set(finishes))
