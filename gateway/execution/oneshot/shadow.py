"""Shadow planning's estimates (sans-I/O): does a plan solved in the background pay?

The executor (``ShadowPolicy``) asks for a solve from where the robots would stand if it
stopped the fleet now -- each robot on the target of the move it is making, or where it stands
-- with the reported blocks as obstacles, and lets the fleet run on meanwhile. When the plan
comes back and the robots still would stop there (no robot started an action since), it
compares two forecasts of the sum of completion times, both Algorithm 1 estimates under the
same belief about the blocks:

* keep the current plan (:func:`forecast_completions`): the monitor's estimates, with every
  action that enters a reported-blocked cell held until the block ends;
* adopt the new plan (:func:`candidate_monitor`, then :func:`forecast_completions`): every
  robot finishes the move it is making, then all wait for the last of them (the stop), then
  the new plan runs from there, its moves into a blocked cell held until the block ends too.

Both are computed in one scenario per probability level of the policy: every open block ends
at that quantile of its duration, the history's conditioned on how long it has lasted
(:meth:`gateway.execution.oneshot.blocks.BlockTracker.end_quantiles`). The plan is adopted (a
replan that needs no solve) only if the policy's risk-aware rule accepts the gains
(:meth:`gateway.execution.oneshot.policies.ShadowPolicy.adopts`): the expected gain less the
expected regret is at least the margin, and the chance of a loss is small. Otherwise it is
dropped and has cost the fleet nothing.
"""

from __future__ import annotations

import heapq
from collections.abc import Mapping, Sequence

from gateway.execution.actions import ActionDurations
from gateway.execution.oneshot.adg import ADG
from gateway.execution.oneshot.monitor import Monitor


def forecast_completions(monitor: Monitor, holds: Mapping[int, float]) -> list[float]:
    """Each robot's estimated completion if vertex ``v`` (not started) of ``holds`` cannot
    start before ``holds[v]``: the monitor's estimates, delayed forward from the held
    vertices through their successors (Algorithm 1's max-plus recurrence)."""
    adg = monitor.adg
    est = monitor.snapshot()
    ts, tc = est.ts, est.tc
    queue = [(adg.step_of[v], v) for v in holds]
    heapq.heapify(queue)
    seen: set[int] = set()
    while queue:
        _, v = heapq.heappop(queue)
        if v in seen:
            continue
        seen.add(v)
        start = max(ts[v], holds.get(v, ts[v]),
                    *(tc[p] for p in adg.predecessors(v)))
        end = start + monitor.tx[v]
        if end > tc[v]:
            ts[v], tc[v] = start, end
            for w in adg.successors(v):
                heapq.heappush(queue, (adg.step_of[w], w))
    out = []
    for r in range(adg.n_robots):
        last = adg.first[r + 1] - 1
        out.append(tc[last] if last >= adg.first[r] else monitor.robot_completion_ms(r))
    return out


def candidate_monitor(adg: ADG, durations: Sequence[ActionDurations], start_ms: float,
                      completions_ms: Sequence[float]) -> Monitor:
    """Algorithm 1's estimates of a new plan (its ``adg``) started by every robot at
    ``start_ms``; a robot with nothing to do keeps ``completions_ms``."""
    tx = [durations[adg.robot_of[v]].of(adg.kind[v]) for v in range(adg.n_vertices)]
    return Monitor(adg, now_ms=start_ms, action_ms=tx, release_ms=start_ms,
                   base_completion_ms=completions_ms)
