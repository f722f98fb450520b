"""The demo's fleet through the real gateway with an intruder whose stay varies: is the
shadow policy ever worse than not replanning? (Not a timed test: a benchmark of outcomes.)

``fleetgate demo``'s setup (the shipped ``lab`` map, ``lab-random-4``, 10 robots, planned
once) runs ``--runs`` times per policy through the gateway over its in-memory transport in
virtual time (``gateway.server.clock.run_virtual``: the same gateway, engine and simulated
fleet as the demo, whose websocket links and real clock only change how long it takes), the
intruder's stay after its robot needs the cell drawn from each run's seed (``--stay``, as
``fleetgate demo --intruder-stay``), the shadow solves charged ``--solver-ms`` of virtual
time. The baseline, measured in the same run, is the same run with the ``none`` policy. The
shadow policy's block history is what the gateway learned in the earlier runs (as one gateway
serving the runs one after the other would: each run adds the blocks it saw). Prints one
line: the runs where shadow was worse than not replanning, and the ratio of the SOCs.
"""

from __future__ import annotations

import fleetgate.userio.script  # noqa: F401 (first: Ctrl-C while importing is one line)

# isort: split

from typing import cast

from fleetgate.userio.exits import CommandParser, run_main
from gateway.execution.oneshot.policies import AUTONOMOUS_POLICIES, PolicyName
from gateway.planning.instance import Instance, load_instance
from gateway.planning.plan import Plan
from gateway.planning.solver import solve
from gateway.runtime import mapstore
from gateway.runtime.deadline import WallDeadline
from gateway.server.clock import VirtualClock, run_virtual
from gateway.server.config import GatewayConfig
from gateway.server.gateway import Gateway
from gateway.server.planner import Problem
from sim_clients.demo_instance import DEFAULT_AGENTS, DEFAULT_MAP, DEFAULT_SCEN
from sim_clients.fleet import fleet_for, run_in_process
from sim_clients.intruder import IntruderConfig
from sim_clients.stays import parse_stay


def run_once(inst: Instance, plan: Plan, seed: int, policy: PolicyName, stay_ms: float,
             history: list[float], solver_ms: float) -> tuple[float, list[float]]:
    """One gateway run in virtual time: its SOC and the blocks the gateway saw."""
    config = GatewayConfig(port=0, map=None, policy=policy, block_history_ms=history)

    async def main() -> tuple[float, list[float]]:
        async with Gateway(config, clock=VirtualClock(solver_time=solver_ms)) as gw:
            fleet = fleet_for(gw, len(plan.paths), gw.connect, seed=seed,
                              intruder_config=IntruderConfig(stay_ms=stay_ms))
            try:
                done = await run_in_process(gw, Problem(inst, DEFAULT_MAP, plan), fleet)
            finally:
                await fleet.stop()
            return done.soc_ms, list(gw.engine.block_history)

    return run_virtual(main())


def main() -> None:
    """Run both policies over the seeds and print the result line."""
    p = CommandParser(description=__doc__)
    p.add_argument("--runs", type=int, default=50)
    p.add_argument("--stay", default="lognormal:5,1")
    p.add_argument("--policy", choices=AUTONOMOUS_POLICIES, default="shadow")
    p.add_argument("--solver-ms", type=float, default=0.0)
    args = p.parse_args()
    stay = parse_stay(args.stay)
    inst = load_instance(mapstore.resolve(DEFAULT_MAP, "map"),
                         mapstore.resolve(DEFAULT_SCEN, "scen"), DEFAULT_AGENTS)
    plan = solve(inst.grid, inst.starts, inst.goals, deadline=WallDeadline(60)).plan
    history: list[float] = []
    worse, total_none, total_policy, costs = 0, 0.0, 0.0, []
    losers: list[int] = []
    for seed in range(args.runs):
        stay_ms = stay.draw_ms(seed)
        none, seen = run_once(inst, plan, seed, "none", stay_ms, [], args.solver_ms)
        got, _ = run_once(inst, plan, seed, cast(PolicyName, args.policy), stay_ms, history,
                          args.solver_ms)
        history = (history + seen)[-100:]
        total_none += none
        total_policy += got
        if got > none:
            worse += 1
            costs.append(got - none)
            losers.append(seed)
    print(f"demo_stays: {args.policy} worse than none in {worse}/{args.runs} gateway runs "
          f"(stay {stay.text}, virtual time, solver {args.solver_ms:g} ms; costs "
          f"{', '.join(f'{c:.0f}' for c in costs) or 'none'} ms, seeds {losers}); SOC ratio "
          f"{args.policy}/none {total_policy / total_none:.4f}")


if __name__ == "__main__":
    run_main("bench/demo_stays.py", main)
