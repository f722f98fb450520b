"""Compiled propagation of the monitor's estimates (numba): the work of every monitor update.

:meth:`gateway.execution.oneshot.monitor.Monitor._propagate` calls it with the vertices whose
inputs changed (a start, a finish, the frontier actions a tick re-clamps, a rewired edge):
they and, in topological order, every descendant whose inputs moved are re-evaluated, and the
propagation stops where a completion time does not change. At a large fleet's tick that is a
small part of the plan's future (about a seventh at 1,000 robots: most late actions are not
what their successors wait for), at a few ns a vertex compiled instead of ~2.5 us in Python.
Compiled with numba for the reasons of :mod:`gateway.planning.bfs_kernel` (``cache=True``:
compiled once per machine).
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt
from numba import njit

_NOT_STARTED, _STARTED, _DONE = 0, 1, 2  # (monitor.NOT_STARTED, STARTED, DONE)


@njit(cache=True, nogil=True)
def propagate(seeds: npt.NDArray[np.int64], level: npt.NDArray[np.int64], top: int,
              succ_ptr: npt.NDArray[np.int64], succ: npt.NDArray[np.int64],
              pred_ptr: npt.NDArray[np.int64], pred: npt.NDArray[np.int64],
              t2_ptr: npt.NDArray[np.int64], t2: npt.NDArray[np.int64],
              robot_of: npt.NDArray[np.int64], is_first: npt.NDArray[np.uint8],
              state: npt.NDArray[np.uint8], remaining: npt.NDArray[np.intc],
              ts: npt.NDArray[np.float64], tc: npt.NDArray[np.float64],
              delta: npt.NDArray[np.float64], release: npt.NDArray[np.float64],
              tx: npt.NDArray[np.float64], hold: npt.NDArray[np.float64], now: float,
              queued: npt.NDArray[np.uint8]) -> None:
    """Re-evaluate ``seeds`` and, level by level (every edge goes to a higher ``level``, all
    below ``top``: a topological order), each successor of a vertex whose t_c changed.

    A vertex not started: ``t_s`` = the max of its predecessors' t_c (its robot's
    ``release`` if it has none), at least ``now`` once every predecessor is done
    (``remaining``), at least its ``hold``; ``t_c = t_s + t_x``. A started one: ``t_c`` =
    ``t_s + t_x``, at least ``now`` and its hold. A done one keeps its real t_c. Then Δ (if it
    has Type 2 tails): the max of their t_c less its Type 1 predecessor's t_c (the robot's
    release for a first action), at least 0. ``hold`` is empty (no holds) or each vertex's
    (-inf: none); ``queued`` is all 0 and is left so."""
    holding = hold.shape[0] > 0
    head = np.full(top, -1, dtype=np.int64)  # a stack of queued vertices per level
    nxt = np.empty(state.shape[0], dtype=np.int64)
    lowest = top
    for v in seeds:
        if not queued[v]:
            queued[v] = 1
            lv = level[v]
            nxt[v] = head[lv]
            head[lv] = v
            if lv < lowest:
                lowest = lv
    lv = lowest
    while lv < top:
        v = head[lv]
        if v < 0:
            lv += 1
            continue
        head[lv] = nxt[v]
        queued[v] = 0
        st = state[v]
        if st == _DONE:
            c = tc[v]
        elif st == _STARTED:
            c = ts[v] + tx[v]
            if c < now:
                c = now
            if holding and c < hold[v]:
                c = hold[v]
        else:
            lo, hi = pred_ptr[v], pred_ptr[v + 1]
            if lo < hi:
                t = tc[pred[lo]]
                for i in range(lo + 1, hi):
                    if tc[pred[i]] > t:  # (Python's max: the first of equals, NaN as it)
                        t = tc[pred[i]]
            else:
                t = release[robot_of[v]]
            if t < now and remaining[v] == 0:
                t = now
            if holding and t < hold[v]:
                t = hold[v]
            ts[v] = t
            c = t + tx[v]
        lo, hi = t2_ptr[v], t2_ptr[v + 1]
        if lo < hi:
            prev = release[robot_of[v]] if is_first[v] else tc[v - 1]
            m = tc[t2[lo]]
            for i in range(lo + 1, hi):
                if tc[t2[i]] > m:
                    m = tc[t2[i]]
            d = m - prev
            if d < 0.0:
                d = 0.0
            delta[v] = d
        if c != tc[v]:  # (also the first evaluation: t_c starts as NaN)
            tc[v] = c
            for i in range(succ_ptr[v], succ_ptr[v + 1]):
                w = succ[i]
                if not queued[w]:
                    queued[w] = 1
                    lw = level[w]
                    nxt[w] = head[lw]
                    head[lw] = w
