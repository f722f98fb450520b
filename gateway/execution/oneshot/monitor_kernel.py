"""Compiled full pass of the monitor (numba): every estimate and Δ of the plan's future.

:meth:`gateway.execution.oneshot.monitor.Monitor._recompute` calls it at a large fleet's
ticks, where re-clamping the late frontier moves most of the plan's future. Vertex by vertex
in level order, the same operations as the monitor's propagation (a max over the
predecessors' t_c, the clamp to ``now``, ``+ t_x``, the holds; Δ from the Type 2 tails), so
the same values; about 20x cheaper than the numpy pass level by level it replaced, whose cost
was a dozen numpy calls per plan step rather than the vertices. Compiled with numba for the
reasons of :mod:`gateway.planning.bfs_kernel` (``cache=True``: compiled once per machine).
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt
from numba import njit

_NOT_STARTED, _STARTED, _DONE = 0, 1, 2  # (monitor.NOT_STARTED, STARTED, DONE)


@njit(cache=True, nogil=True)
def recompute(order: npt.NDArray[np.int64], layer_ptr: npt.NDArray[np.int64], done: int,
              pred_ptr: npt.NDArray[np.int64], pred: npt.NDArray[np.int64],
              t2_ptr: npt.NDArray[np.int64], t2: npt.NDArray[np.int64],
              robot_of: npt.NDArray[np.int64], is_first: npt.NDArray[np.uint8],
              state: npt.NDArray[np.uint8], remaining: npt.NDArray[np.intc],
              ts: npt.NDArray[np.float64], tc: npt.NDArray[np.float64],
              delta: npt.NDArray[np.float64], release: npt.NDArray[np.float64],
              tx: npt.NDArray[np.float64], hold: npt.NDArray[np.float64], now: float) -> int:
    """Recompute t_s, t_c (vertices not done) and Δ (vertices with Type 2 tails) of the
    vertices ``order[layer_ptr[done]:]``, in that order (levels ascending: every edge goes
    to a higher level). ``hold`` is empty (no holds) or each vertex's hold (-inf: none).
    Returns how many leading layers are now all done (their values are final)."""
    holding = hold.shape[0] > 0
    for k in range(layer_ptr[done], order.shape[0]):
        v = order[k]
        st = state[v]
        if st == _NOT_STARTED:
            lo, hi = pred_ptr[v], pred_ptr[v + 1]
            if lo < hi:
                t = tc[pred[lo]]
                for i in range(lo + 1, hi):
                    c = tc[pred[i]]
                    if c > t:
                        t = c
            else:
                t = release[robot_of[v]]
            if t < now and remaining[v] == 0:
                t = now
            if holding and t < hold[v]:
                t = hold[v]
            ts[v] = t
            tc[v] = t + tx[v]
        elif st == _STARTED:
            c = ts[v] + tx[v]
            if c < now:
                c = now
            if holding and c < hold[v]:
                c = hold[v]
            tc[v] = c
        lo, hi = t2_ptr[v], t2_ptr[v + 1]
        if lo < hi:
            prev = release[robot_of[v]] if is_first[v] else tc[v - 1]
            m = tc[t2[lo]]
            for i in range(lo + 1, hi):
                c = tc[t2[i]]
                if c > m:
                    m = c
            d = m - prev
            if d < 0.0:
                d = 0.0
            delta[v] = d
    layers = layer_ptr.shape[0] - 1
    while done < layers:
        for k in range(layer_ptr[done], layer_ptr[done + 1]):
            if state[order[k]] != _DONE:
                return done
        done += 1
    return done
