"""Execution monitoring (DESIGN section 2): Algorithm 1 estimates and slack, incrementally.

Estimates: ``t_s(a) = max t_c(p)`` over the predecessors of ``a`` (the robot's release time if
it has none), ``t_c(a) = t_s(a) + t_x(a)`` (``t_x`` per action: its kind -- move, turn, wait --
and its robot's model decide it); completed actions use their real times; a started,
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
changed, in topological order, and stops where values do not change (compiled:
:mod:`gateway.execution.oneshot.monitor_kernel`); fleet and robot slack are numpy maxima over
the not-started vertices. :func:`algorithm1` is the
plain full recomputation (the paper's Algorithm 1, timestep by timestep); tests use it as the
oracle and ``bench/monitor.py`` as the baseline.
"""

from __future__ import annotations

import copy
import heapq
import math
from array import array
from collections.abc import Iterable, Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from gateway.execution.errors import ExecutionError
from gateway.execution.oneshot.adg import ADG
from gateway.execution.oneshot.monitor_kernel import propagate
from gateway.execution.params import PAPER
from gateway.planning.plan import Plan

NOT_STARTED, STARTED, DONE = 0, 1, 2
_READY_KIND, _STARTED_KIND = 0, 1
IntArray = npt.NDArray[np.int64]


@dataclass(frozen=True)
class _Graph:
    """An ADG as the compiled propagation reads it (:func:`~gateway.execution.oneshot.
    monitor_kernel.propagate`): its CSR arrays, each vertex's level (``top``: above them all),
    robot and first-action flag."""

    level: IntArray
    top: int
    succ_ptr: IntArray
    succ: IntArray
    pred_ptr: IntArray
    pred: IntArray
    t2_ptr: IntArray
    t2: IntArray
    robot_of: IntArray
    is_first: npt.NDArray[np.uint8]

    @classmethod
    def of(cls, adg: ADG) -> _Graph:
        """``adg``'s arrays."""
        level = np.asarray(adg.level, dtype=np.int64)
        return cls(level, int(level.max()) + 1 if level.size else 0,
                   np.asarray(adg.succ_ptr, np.int64), np.asarray(adg.succ, np.int64),
                   np.asarray(adg.pred_ptr, np.int64), np.asarray(adg.pred, np.int64),
                   np.asarray(adg.t2_pred_ptr, np.int64), np.asarray(adg.t2_pred, np.int64),
                   np.asarray(adg.robot_of, np.int64),
                   np.frombuffer(bytes(adg.is_first), np.uint8))


_NO_HOLDS = np.empty(0, dtype=np.float64)


def _per_vertex(action_ms: float | Sequence[float], nv: int) -> array[float]:
    """``t_x`` of every vertex from one value for all or a per-vertex sequence."""
    if isinstance(action_ms, int | float):
        out = array("d", [float(action_ms)]) * nv
    else:
        out = array("d", (float(x) for x in action_ms))
        if len(out) != nv:
            raise ExecutionError(f"expected {nv} per-action durations, got {len(out)}")
    if not all(math.isfinite(x) and x > 0 for x in out):
        raise ExecutionError("action durations must be positive numbers of ms")
    return out


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
    :meth:`action_started` and :meth:`action_finished` (vertex ids of ``adg``). ``action_ms``
    is ``t_x``: one value for every action, or one per vertex.
    """

    def __init__(self, adg: ADG, *, now_ms: float,
                 action_ms: float | Sequence[float] = PAPER.action_ms,
                 release_ms: float | Sequence[float] | None = None,
                 base_completion_ms: Sequence[float] | None = None) -> None:
        n, nv = adg.n_robots, adg.n_vertices
        self.adg = adg
        self.tx = _per_vertex(action_ms, nv)
        """``t_x`` of each vertex (ms)."""
        self.now_ms = float(now_ms)
        self.release_ms = _per_robot(release_ms, self.now_ms, n)
        # completion of a robot that has no action in this plan (its previous completion)
        self._base_completion = _per_robot(base_completion_ms, 0.0, n)
        # flat arrays: fast to index one by one, and numpy views of them (below) without copies
        self._state = bytearray(nv)
        self._remaining = array("i", (adg.pred_ptr[v + 1] - adg.pred_ptr[v] for v in range(nv)))
        self._ts = array("d", bytes(8 * nv))
        self._delta = array("d", bytes(8 * nv))
        self._next = list(adg.first[:-1])  # each robot's first unfinished vertex
        # frontier clamping: (threshold, vertex, kind); the vertex's value follows `now` once
        # now > threshold; such vertices are kept in `_active`
        self._thresholds: list[tuple[float, int, int]] = []
        self._active: set[int] = set()
        self._queued = np.zeros(nv, np.uint8)  # the kernel's scratch: queued for evaluation
        self._tc = array("d", [math.nan]) * nv  # every vertex "changes" at first evaluation
        self._graph: _Graph | None = None  # the ADG's arrays, built on first use
        self._hold_np = _NO_HOLDS  # see with_holds
        # seeds of starts and finishes not yet propagated: the work is deferred to the next
        # query or clamping step, so a burst of events between two ticks costs one pass over
        # the union of their descendants instead of one pass each (same values: every vertex
        # is a function of its predecessors, evaluated in topological order)
        self._pending: list[int] = []
        self._delta0 = self._delta  # (a copy of Δ once it is computed, below)
        self._views()
        self._propagate(range(nv))
        ready = np.flatnonzero(np.frombuffer(self._remaining, np.intc) == 0)
        self._thresholds = [(self._ts[v], v, _READY_KIND) for v in ready.tolist()]
        heapq.heapify(self._thresholds)
        self._delta0 = array("d", self._delta)
        self._views()

    def rewired(self, adg: ADG) -> Monitor:
        """A copy of this monitor on ``adg``: the same actions (vertex ids) with other Type 2
        edges (a rescheduled ADG). Every action keeps its state, real times and Δ0; only
        the actions whose incoming edges changed, and what follows them, are re-evaluated.
        This monitor is left as it was."""
        old = self.adg
        if adg.n_vertices != old.n_vertices or adg.first != old.first:
            raise ExecutionError("a rewired monitor needs the same actions")
        self._flush()
        out = copy.copy(self)
        out.adg = adg
        out._state = bytearray(self._state)
        out._remaining = array("i", self._remaining)
        out._ts, out._tc = array("d", self._ts), array("d", self._tc)
        out._delta, out._delta0 = array("d", self._delta), array("d", self._delta0)
        out._next = list(self._next)
        out._thresholds = list(self._thresholds)
        out._active = set(self._active)
        out._queued = np.zeros(len(self._queued), np.uint8)
        out._graph = None if adg is not old else self._graph
        out._pending = []
        changed = [v for v in range(adg.n_vertices)
                   if adg.predecessors(v) != old.predecessors(v)]
        for v in changed:
            out._remaining[v] = sum(1 for p in adg.predecessors(v) if out._state[p] != DONE)
            if adg.t2_pred_ptr[v] == adg.t2_pred_ptr[v + 1]:
                out._delta[v] = 0.0  # (propagation sets Δ only where there are Type 2 edges)
            if out._state[v] == NOT_STARTED and out._remaining[v] == 0:
                base = max((out._tc[p] for p in adg.predecessors(v)),
                           default=out.release_ms[adg.robot_of[v]])
                heapq.heappush(out._thresholds, (base, v, _READY_KIND))
                if base < out.now_ms:
                    out._active.add(v)
        out._views()
        out._propagate(changed)
        return out

    def with_holds(self, holds: dict[int, float]) -> Monitor:
        """A copy of this monitor for what-if estimates in which each vertex ``v`` of
        ``holds`` cannot start (not started) or finish (started) before ``holds[v]``: a robot
        waiting for a blocked cell until the block's expected end, an action that runs late.
        Its copies (:meth:`rewired`) keep the holds. This monitor is left as it was."""
        out = self.rewired(self.adg)
        out._hold_np = np.full(self.adg.n_vertices, -math.inf)
        for v, until in holds.items():
            out._hold_np[v] = until
        out._propagate(list(holds))
        return out

    def __getstate__(self) -> dict[str, object]:
        """The state without the numpy views: a copy (``copy``, ``deepcopy``, pickle) makes
        its own views of its own flat arrays (a copied view would be a separate array that no
        longer sees them)."""
        return {k: v for k, v in self.__dict__.items() if not k.startswith("_np_")}

    def __setstate__(self, state: dict[str, object]) -> None:
        """Restore a copy's state and view its flat arrays."""
        self.__dict__.update(state)
        self._views()

    def _views(self) -> None:
        """numpy views of the flat arrays (no copies)."""
        self._np_state = np.frombuffer(self._state, np.uint8)
        self._np_remaining = np.frombuffer(self._remaining, np.intc)
        self._np_ts = np.frombuffer(self._ts, np.float64)
        self._np_tc = np.frombuffer(self._tc, np.float64)
        self._np_delta = np.frombuffer(self._delta, np.float64)
        self._np_delta0 = np.frombuffer(self._delta0, np.float64)
        self._np_tx = np.frombuffer(self.tx, np.float64)
        self._np_release = np.asarray(self.release_ms, dtype=np.float64)  # (never changes)

    # ----------------------------------------------------------------- evaluation
    def _propagate(self, seeds: Iterable[int]) -> None:
        """Re-evaluate ``seeds`` and, in topological order, every descendant whose inputs moved
        (compiled: :func:`~gateway.execution.oneshot.monitor_kernel.propagate`).

        A vertex's (t_s, t_c) follow from its predecessors' t_c (or its robot's release time),
        its real times and the clamping time; its Δ from its Type 2 tails' t_c and its Type 1
        predecessor's t_c. Successors are re-evaluated only if t_c changed.
        """
        g = self._graph
        if g is None:
            g = self._graph = _Graph.of(self.adg)
        propagate(np.fromiter(seeds, np.int64), g.level, g.top, g.succ_ptr, g.succ,
                  g.pred_ptr, g.pred, g.t2_ptr, g.t2, g.robot_of, g.is_first, self._np_state,
                  self._np_remaining, self._np_ts, self._np_tc, self._np_delta,
                  self._np_release, self._np_tx, self._hold_np,
                  self.now_ms, self._queued)

    def _flush(self) -> None:
        """Propagate the deferred starts and finishes (before any estimate is read)."""
        if self._pending:
            seeds, self._pending = self._pending, []
            self._propagate(seeds)

    def _max_growth(self, lo: int, hi: int) -> float:
        """Largest Δ̄ over the not-started vertices ``lo..hi-1`` (0 if there is none)."""
        waiting = self._np_state[lo:hi] == NOT_STARTED
        if not waiting.any():
            return 0.0
        growth = self._np_delta[lo:hi] - self._np_delta0[lo:hi]
        return float(growth[waiting].max())

    def growth(self) -> npt.NDArray[np.float64]:
        """Δ̄ of every vertex (a copy): what :meth:`keep_growth` restores."""
        self._flush()
        return self._np_delta - self._np_delta0

    def keep_growth(self, growth: npt.NDArray[np.float64]) -> None:
        """Move Δ0 so that Δ̄ is ``growth`` again (from :meth:`growth` on this monitor): the
        change of Δ since then stops counting as slack growth. After a pause, the waiting
        that standing still caused everyone is not a delay that replanning could mend."""
        if growth.shape != self._np_delta.shape:
            raise ExecutionError("growth of another plan's monitor")
        self._flush()
        self._np_delta0[:] = self._np_delta - growth

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
        thresholds, active = self._thresholds, self._active
        if now_ms > self.now_ms:
            while thresholds and thresholds[0][0] < now_ms:
                _, v, kind = heapq.heappop(thresholds)
                if self._state[v] == (NOT_STARTED if kind == _READY_KIND else STARTED):
                    active.add(v)
        self._flush()  # at the clamping time the deferred events happened under
        if now_ms == self.now_ms:
            return
        self.now_ms = float(now_ms)
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
        heapq.heappush(self._thresholds, (at_ms + self.tx[v], v, _STARTED_KIND))
        self._pending.append(v)

    def action_cancelled(self, v: int) -> None:
        """Vertex ``v`` (started, a move stopped on the way) was cancelled: its robot is back
        on the source cell and the action has not started after all."""
        if self._state[v] != STARTED:
            raise ExecutionError(f"vertex {v} cannot be cancelled: it is not running")
        self._state[v] = NOT_STARTED
        preds = self.adg.predecessors(v)
        base = max((self._tc[p] for p in preds), default=self.release_ms[self.adg.robot_of[v]])
        heapq.heappush(self._thresholds, (base, v, _READY_KIND))
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
        return self._max_growth(self.adg.first[robot], self.adg.first[robot + 1])

    def fleet_slack(self) -> float:
        """Δ̄F: the largest Δ̄ over all actions not yet started (0 if none is left)."""
        self._flush()
        return self._max_growth(0, self.adg.n_vertices)

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


def warm_up() -> None:
    """Load the compiled propagation now (from numba's cache; compiled on a machine's first
    use) on a one-robot plan, so that its arguments' types are those of every run: a gateway
    calls this as it starts, else its first run's start pays it (~0.1 s of the owner task,
    the whole fleet waiting for its first actions)."""
    Monitor(ADG(Plan((((0, 0), (1, 0)),))), now_ms=0.0)


@dataclass(frozen=True)
class Estimate:
    """Per-vertex start and completion times and slack (Δ; Δ0 where known)."""

    ts: list[float]
    tc: list[float]
    delta: list[float]
    delta0: list[float]


def algorithm1(adg: ADG, *, now_ms: float, action_ms: float | Sequence[float],
               release_ms: Sequence[float], started_ms: Sequence[float | None],
               finished_ms: Sequence[float | None]) -> Estimate:
    """Full recomputation of estimates and Δ (Algorithm 1, timestep by timestep).

    ``started_ms[v]`` / ``finished_ms[v]`` are the real times of vertex ``v`` (None if it has
    not started / finished yet); ``action_ms`` is ``t_x`` for all vertices or per vertex.
    Independent of :class:`Monitor`'s incremental bookkeeping; ``delta0`` of the result is
    empty.
    """
    nv = adg.n_vertices
    tx = [float(action_ms)] * nv if isinstance(action_ms, int | float) else list(action_ms)
    ts, tc, delta = [0.0] * nv, [0.0] * nv, [0.0] * nv
    by_step: dict[int, list[int]] = {}
    for v in range(nv):
        by_step.setdefault(adg.level[v], []).append(v)
    for step in sorted(by_step):
        for v in by_step[step]:
            preds = adg.predecessors(v)
            done_at, begun_at = finished_ms[v], started_ms[v]
            if done_at is not None and begun_at is not None:
                ts[v], tc[v] = begun_at, done_at
            elif begun_at is not None:
                ts[v], tc[v] = begun_at, max(begun_at + tx[v], now_ms)
            else:
                start = max((tc[p] for p in preds), default=release_ms[adg.robot_of[v]])
                if all(finished_ms[p] is not None for p in preds):
                    start = max(start, now_ms)
                ts[v], tc[v] = start, start + tx[v]
            tails = adg.t2_pred[adg.t2_pred_ptr[v] : adg.t2_pred_ptr[v + 1]]
            if tails:
                p = adg.t1_pred(v)
                prev = tc[p] if p >= 0 else release_ms[adg.robot_of[v]]
                delta[v] = max(0.0, *(tc[u] - prev for u in tails))
    return Estimate(ts, tc, delta, [])
