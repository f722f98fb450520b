"""Execution monitoring (DESIGN section 2): Algorithm 1 estimates and slack, incrementally.

Estimates: ``t_s(a) = max t_c(p)`` over the predecessors of ``a`` (the robot's release time if
it has none), ``t_c(a) = t_s(a) + t_x``; completed actions use their real times; a started,
unfinished action has ``t_c = max(t_s + t_x, now)``; an action whose predecessors are all done
cannot start before ``now``. ``now`` is the monitor's clamping time: the latest
:meth:`Monitor.advance` (the executor's latest tick), so the present is seen at the tick
resolution while real start and finish times are used exactly.

Slack: for a Type 2 edge ``e = (a_i^{r1} -> a_j^{r2})``,
``δ(e) = t_c(a_i^{r1}) - t_c(a_{j-1}^{r2})`` (r2's release time for its first action),
``Δ(a) = max(0, max δ(e))`` over incoming Type 2 edges, ``Δ0`` is Δ on the initial estimate,
``Δ̄ = Δ - Δ0`` and the fleet slack ``Δ̄F`` is the largest Δ̄ over actions not yet started (0 if
none is left).

:class:`Monitor` keeps all of this up to date by re-evaluating only the descendants of what
changed, in topological order, and stops where values do not change. :func:`algorithm1` is the
plain full recomputation (the paper's Algorithm 1, timestep by timestep); tests use it as the
oracle and ``bench/monitor.py`` as the baseline.
"""

from __future__ import annotations

import heapq
import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass

from gateway.execution.adg import ADG
from gateway.execution.errors import ExecutionError

NOT_STARTED, STARTED, DONE = 0, 1, 2
_READY_KIND, _STARTED_KIND = 0, 1


def _per_robot(value: float | Sequence[float] | None, default: float, n: int) -> list[float]:
    """A per-robot list from a scalar, a sequence or None (``default`` for everyone)."""
    if value is None:
        return [default] * n
    if isinstance(value, int | float):
        return [float(value)] * n
    out = [float(x) for x in value]
    if len(out) != n:
        raise ExecutionError(f"expected {n} per-robot values, got {len(out)}")
    return out


class Monitor:
    """Estimates (Algorithm 1) and slack of one plan's ADG, updated incrementally.

    The executor reports progress with :meth:`advance` (the present moved on),
    :meth:`action_started` and :meth:`action_finished` (vertex ids of ``adg``).
    """

    def __init__(self, adg: ADG, *, now_ms: float, action_ms: float = 1000.0,
                 release_ms: float | Sequence[float] | None = None,
                 base_completion_ms: Sequence[float] | None = None) -> None:
        n, nv = adg.n_robots, adg.n_vertices
        self.adg = adg
        self.action_ms = float(action_ms)
        self.now_ms = float(now_ms)
        self.release_ms = _per_robot(release_ms, self.now_ms, n)
        # completion of a robot that has no action in this plan (its previous completion)
        self._base_completion = _per_robot(base_completion_ms, 0.0, n)
        self._state = bytearray(nv)
        self._remaining = [0] * nv  # unfinished predecessors
        for v in range(nv):
            self._remaining[v] = adg.pred_ptr[v + 1] - adg.pred_ptr[v]
        self._ts = [0.0] * nv
        self._delta = [0.0] * nv
        self._next = list(adg.first[:-1])  # each robot's first unfinished vertex
        # frontier clamping: (threshold, vertex, kind); the vertex's value follows `now` once
        # now > threshold; such vertices are kept in `_active`
        self._thresholds: list[tuple[float, int, int]] = []
        self._active: set[int] = set()
        self._queued = bytearray(nv)
        self._tc = [math.nan] * nv  # every vertex "changes" on the first evaluation
        self._delta0 = self._delta  # placeholder until the initial estimate is known
        # lazy max-heaps of Δ̄ over not-started vertices: (-Δ̄, vertex, version)
        self._version = [0] * nv
        self._fleet: list[tuple[float, int, int]] = []
        self._robot_heaps: list[list[tuple[float, int, int]]] = [[] for _ in range(n)]
        # seeds of starts and finishes not yet propagated: the work is deferred to the next
        # query or clamping step, so a burst of events between two ticks costs one pass over
        # the union of their descendants instead of one pass each (same values: every vertex
        # is a function of its predecessors, evaluated in topological order)
        self._pending: list[int] = []
        self._propagate(range(nv))
        for v in range(nv):
            if self._remaining[v] == 0:
                heapq.heappush(self._thresholds, (self._ts[v], v, _READY_KIND))
        self._delta0 = list(self._delta)
        self._rebuild_heaps()

    # ----------------------------------------------------------------- evaluation
    def _propagate(self, seeds: Iterable[int]) -> None:
        """Re-evaluate ``seeds`` and, in topological order, every descendant whose inputs moved.

        A vertex's (t_s, t_c) follow from its predecessors' t_c (or its robot's release time),
        its real times and the clamping time; its Δ from its Type 2 tails' t_c and its Type 1
        predecessor's t_c. Successors are re-evaluated only if t_c changed.
        """
        adg = self.adg
        step_of, queued = adg.step_of, self._queued
        pred_ptr, pred, succ_ptr, succ = adg.pred_ptr, adg.pred, adg.succ_ptr, adg.succ
        t2_ptr, t2, is_first, robot_of = adg.t2_pred_ptr, adg.t2_pred, adg.is_first, adg.robot_of
        state, remaining, release = self._state, self._remaining, self.release_ms
        ts_of, tc_of, delta = self._ts, self._tc, self._delta
        now, tx = self.now_ms, self.action_ms
        # Every edge goes from a plan step to a later one (ADG.order), so visiting the dirty
        # vertices step by step is a topological order; a bucket per step and a heap of the
        # steps that have one is much cheaper than a heap of vertices (a tick re-clamps
        # every late frontier action and moves most of the plan's future).
        buckets: dict[int, list[int]] = {}
        steps: list[int] = []
        for v in seeds:
            if not queued[v]:
                queued[v] = 1
                bucket = buckets.get(step_of[v])
                if bucket is None:
                    buckets[step_of[v]] = [v]
                    steps.append(step_of[v])
                else:
                    bucket.append(v)
        heapq.heapify(steps)
        while steps:
            for v in buckets.pop(heapq.heappop(steps)):
                queued[v] = 0
                st = state[v]
                if st == DONE:
                    tc = tc_of[v]
                elif st == STARTED:
                    tc = ts_of[v] + tx
                    if tc < now:
                        tc = now
                else:
                    lo, hi = pred_ptr[v], pred_ptr[v + 1]
                    ts = max([tc_of[p] for p in pred[lo:hi]]) if lo < hi \
                        else release[robot_of[v]]
                    if ts < now and remaining[v] == 0:
                        ts = now
                    ts_of[v] = ts
                    tc = ts + tx
                lo, hi = t2_ptr[v], t2_ptr[v + 1]
                if lo < hi:
                    prev = release[robot_of[v]] if is_first[v] else tc_of[v - 1]
                    d = max([tc_of[u] for u in t2[lo:hi]]) - prev
                    if d < 0.0:
                        d = 0.0
                    if d != delta[v]:
                        delta[v] = d
                        if not state[v]:  # NOT_STARTED: only those count for the slack
                            self._push_slack(v)
                if tc != tc_of[v]:
                    tc_of[v] = tc
                    for w in succ[succ_ptr[v] : succ_ptr[v + 1]]:
                        if not queued[w]:
                            queued[w] = 1
                            bucket = buckets.get(step_of[w])
                            if bucket is None:
                                buckets[step_of[w]] = [w]
                                heapq.heappush(steps, step_of[w])
                            else:
                                bucket.append(w)

    def _flush(self) -> None:
        """Propagate the deferred starts and finishes (before any estimate is read)."""
        if self._pending:
            seeds, self._pending = self._pending, []
            self._propagate(seeds)

    # ----------------------------------------------------------------- slack heaps
    def _push_slack(self, v: int) -> None:
        if self._state[v] != NOT_STARTED:
            return
        self._version[v] += 1
        entry = (self._delta0[v] - self._delta[v], v, self._version[v])
        heapq.heappush(self._fleet, entry)
        robot_heap = self._robot_heaps[self.adg.robot_of[v]]
        heapq.heappush(robot_heap, entry)
        if len(self._fleet) > 2 * self.adg.n_vertices + 64:
            self._rebuild_heaps()

    def _rebuild_heaps(self) -> None:
        """Fresh heaps holding exactly the current Δ̄ of every not-started vertex."""
        self._fleet = []
        self._robot_heaps = [[] for _ in range(self.adg.n_robots)]
        for v in range(self.adg.n_vertices):
            if self._state[v] == NOT_STARTED:
                self._version[v] += 1
                entry = (self._delta0[v] - self._delta[v], v, self._version[v])
                self._fleet.append(entry)
                self._robot_heaps[self.adg.robot_of[v]].append(entry)
        heapq.heapify(self._fleet)
        for h in self._robot_heaps:
            heapq.heapify(h)

    def _heap_max(self, heap: list[tuple[float, int, int]]) -> float:
        while heap:
            neg, v, version = heap[0]
            if version == self._version[v] and self._state[v] == NOT_STARTED:
                return -neg
            heapq.heappop(heap)
        return 0.0

    # ----------------------------------------------------------------- progress
    def _check_time(self, now_ms: float) -> None:
        if not now_ms >= self.now_ms:  # also rejects NaN
            raise ExecutionError(f"time went backwards: {now_ms} ms < {self.now_ms} ms")

    def advance(self, now_ms: float) -> None:
        """The present is ``now_ms``: re-clamp the frontier actions that are past due.

        Only this moves the clamping time ``now_ms`` (the executor calls it at its ticks, every
        ``MONITOR_PERIOD_MS``); starts and finishes in between carry their own real times.
        """
        self._check_time(now_ms)
        self._flush()  # at the clamping time the deferred events happened under
        if now_ms == self.now_ms:
            return
        self.now_ms = float(now_ms)
        thresholds, active = self._thresholds, self._active
        while thresholds and thresholds[0][0] < now_ms:
            _, v, kind = heapq.heappop(thresholds)
            if self._state[v] == (NOT_STARTED if kind == _READY_KIND else STARTED):
                active.add(v)
        if active:
            self._propagate(list(active))

    def is_ready(self, v: int) -> bool:
        """True if every predecessor of vertex ``v`` is done."""
        return self._remaining[v] == 0

    def action_started(self, v: int, at_ms: float) -> None:
        """Vertex ``v`` (ready, not started) began at ``at_ms`` (>= the clamping time)."""
        self._check_time(at_ms)
        if self._state[v] != NOT_STARTED or self._remaining[v]:
            raise ExecutionError(f"vertex {v} cannot start: it is not ready or already started")
        self._state[v] = STARTED
        self._active.discard(v)
        self._ts[v] = float(at_ms)
        heapq.heappush(self._thresholds, (at_ms + self.action_ms, v, _STARTED_KIND))
        self._pending.append(v)

    def action_finished(self, v: int, at_ms: float) -> list[int]:
        """Vertex ``v`` (started) finished at ``at_ms``; returns the vertices now ready."""
        self._check_time(at_ms)
        if self._state[v] != STARTED:
            raise ExecutionError(f"vertex {v} cannot finish: it is not running")
        self._state[v] = DONE
        self._active.discard(v)
        self._tc[v] = float(at_ms)
        robot = self.adg.robot_of[v]
        self._next[robot] = v + 1
        ready = []
        succ = self.adg.successors(v)
        for w in succ:
            self._remaining[w] -= 1
            if self._remaining[w] == 0:
                ready.append(w)
                base = max(self._tc[p] for p in self.adg.predecessors(w))
                heapq.heappush(self._thresholds, (base, w, _READY_KIND))
        self._pending.extend(succ)
        return ready

    # ----------------------------------------------------------------- queries
    def next_vertex(self, robot: int) -> int:
        """The robot's first unfinished vertex, or -1 if it has finished them all."""
        v = self._next[robot]
        return v if v < self.adg.first[robot + 1] else -1

    def state(self, v: int) -> int:
        """NOT_STARTED, STARTED or DONE."""
        return self._state[v]

    def start_ms(self, robot: int, action: int) -> float:
        """Estimated (or real, once started) start time of ``a_action^robot``."""
        self._flush()
        return self._ts[self.adg.vertex(robot, action)]

    def completion_ms(self, robot: int, action: int) -> float:
        """Estimated (or real, once done) completion time t_c of ``a_action^robot``."""
        self._flush()
        return self._tc[self.adg.vertex(robot, action)]

    def action_slack(self, robot: int, action: int) -> float:
        """Δ(a): how long the robot is expected to wait for others before starting a."""
        self._flush()
        return self._delta[self.adg.vertex(robot, action)]

    def initial_slack(self, robot: int, action: int) -> float:
        """Δ0(a): Δ(a) on the plan's initial estimate."""
        return self._delta0[self.adg.vertex(robot, action)]

    def slack_growth(self, robot: int, action: int) -> float:
        """Δ̄(a) = Δ(a) - Δ0(a): extra waiting caused by other robots' delays."""
        self._flush()
        v = self.adg.vertex(robot, action)
        return self._delta[v] - self._delta0[v]

    def robot_slack(self, robot: int) -> float:
        """Largest Δ̄ over the robot's actions not yet started (0 if none is left)."""
        if not 0 <= robot < self.adg.n_robots:
            raise ExecutionError(f"unknown robot {robot} (the plan has {self.adg.n_robots} robots)")
        self._flush()
        return self._heap_max(self._robot_heaps[robot])

    def fleet_slack(self) -> float:
        """Δ̄F: the largest Δ̄ over all actions not yet started (0 if none is left)."""
        self._flush()
        return self._heap_max(self._fleet)

    def robot_completion_ms(self, robot: int) -> float:
        """Estimated completion time of the robot's last action (its previous one if none)."""
        self._flush()
        last = self.adg.first[robot + 1] - 1
        return self._tc[last] if last >= self.adg.first[robot] else self._base_completion[robot]

    def estimated_soc_ms(self) -> float:
        """Estimated final sum of completion times (ms)."""
        return sum(self.robot_completion_ms(r) for r in range(self.adg.n_robots))

    def estimated_makespan_ms(self) -> float:
        """Estimated final makespan (ms)."""
        return max((self.robot_completion_ms(r) for r in range(self.adg.n_robots)), default=0.0)

    def blocking_edges(self) -> list[tuple[int, int, int, int]]:
        """Who waits for whom now: ``(robot, action, waits_for_robot, its_action)``.

        The Type 2 edges whose tail is not done and whose head is its robot's next action.
        """
        adg, out = self.adg, []
        for robot in range(adg.n_robots):
            v = self._next[robot]
            if v >= adg.first[robot + 1] or self._state[v] != NOT_STARTED:
                continue
            for u in adg.t2_pred[adg.t2_pred_ptr[v] : adg.t2_pred_ptr[v + 1]]:
                if self._state[u] != DONE:
                    out.append((robot, adg.step_of[v], adg.robot_of[u], adg.step_of[u]))
        return out

    def snapshot(self) -> Estimate:
        """Copies of the current per-vertex t_s, t_c, Δ and Δ0 (indexed by vertex id)."""
        self._flush()
        return Estimate(list(self._ts), list(self._tc), list(self._delta), list(self._delta0))


@dataclass(frozen=True)
class Estimate:
    """Per-vertex start and completion times and slack (Δ; Δ0 where known)."""

    ts: list[float]
    tc: list[float]
    delta: list[float]
    delta0: list[float]


def algorithm1(adg: ADG, *, now_ms: float, action_ms: float,
               release_ms: Sequence[float], started_ms: Sequence[float | None],
               finished_ms: Sequence[float | None]) -> Estimate:
    """Full recomputation of estimates and Δ (Algorithm 1, timestep by timestep).

    ``started_ms[v]`` / ``finished_ms[v]`` are the real times of vertex ``v`` (None if it has
    not started / finished yet). Independent of :class:`Monitor`'s incremental bookkeeping;
    ``delta0`` of the result is empty.
    """
    nv = adg.n_vertices
    ts, tc, delta = [0.0] * nv, [0.0] * nv, [0.0] * nv
    by_step: dict[int, list[int]] = {}
    for v in range(nv):
        by_step.setdefault(adg.step_of[v], []).append(v)
    for step in sorted(by_step):
        for v in by_step[step]:
            preds = adg.predecessors(v)
            done_at, begun_at = finished_ms[v], started_ms[v]
            if done_at is not None and begun_at is not None:
                ts[v], tc[v] = begun_at, done_at
            elif begun_at is not None:
                ts[v], tc[v] = begun_at, max(begun_at + action_ms, now_ms)
            else:
                start = max((tc[p] for p in preds), default=release_ms[adg.robot_of[v]])
                if all(finished_ms[p] is not None for p in preds):
                    start = max(start, now_ms)
                ts[v], tc[v] = start, start + action_ms
            tails = adg.t2_pred[adg.t2_pred_ptr[v] : adg.t2_pred_ptr[v + 1]]
            if tails:
                p = adg.t1_pred(v)
                prev = tc[p] if p >= 0 else release_ms[adg.robot_of[v]]
                delta[v] = max(0.0, *(tc[u] - prev for u in tails))
    return Estimate(ts, tc, delta, [])
