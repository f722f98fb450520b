"""Traffic guidance for the ``turning`` planner: soft one-way lanes and the tables they weigh.

A guidance gives every ``turning`` state ``4 * cell + heading`` the cost of its forward move;
a turn and a wait cost :data:`MOVE`. :func:`crisscross` is the hand-made guidance of the
guidance-graph literature (Zhang et al., "Guidance Graph Optimization for Lifelong MAPF",
IJCAI 2024; the LoRR 2023 winner's WPPL, arXiv 2404.16162, optimises one instead): even rows
run east, odd rows west, even columns south, odd columns north, and a move against its lane
costs ``penalty`` more. Robots still go anywhere (the lanes are soft), but opposite flows
mostly take different lanes, so fewer robots meet head-on, where the 1-robust rule and the
cost of turning round hurt most. :func:`guided_tables` are the exact costs to a goal under a
guidance (a Dijkstra search backwards over the states with two FIFO queues, compiled with
numba as :mod:`gateway.planning.bfs_kernel` is).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import numpy.typing as npt
from numba import njit

from gateway.planning.distance import turning_predecessor_table
from gateway.planning.grid import Grid

MOVE = 2
"""Cost of one action (a move along its lane, a turn, a wait) in a guided table: an even unit,
so half a move can be a penalty."""


def crisscross(grid: Grid, penalty: int) -> npt.NDArray[np.int32]:
    """The forward-move cost of each state ``4 * cell + heading`` (headings east, south,
    west, north): :data:`MOVE`, plus ``penalty`` against the lane (even rows east, odd rows
    west, even columns south, odd columns north)."""
    if penalty < 0:
        raise ValueError(f"a lane penalty must be at least 0, not {penalty}")
    cells = np.arange(grid.size)
    x, y = cells % grid.width, cells // grid.width
    along = np.stack([y % 2 == 0, x % 2 == 0, y % 2 == 1, x % 2 == 1], axis=1)
    return np.where(along, MOVE, MOVE + penalty).astype(np.int32).ravel()


@njit(cache=True, nogil=True)
def _two_queue_groups(table: npt.NDArray[np.int32], forward: npt.NDArray[np.int32],
                      sources: npt.NDArray[np.int64], bounds: npt.NDArray[np.int64],
                      out: npt.NDArray[np.int32]) -> None:
    """Fill ``out[k]`` (all -1) with the cheapest costs to the sources
    ``sources[bounds[k]:bounds[k + 1]]``: ``table`` is :func:`turning_predecessor_table`
    (columns 0 and 1 turn into the state, column 2 moves forward into it), a turn costs
    ``MOVE``, the forward move out of state u ``forward[u]``: ``MOVE`` or one other cost.

    Dijkstra with two FIFO queues instead of a heap: states are popped in increasing cost,
    so the costs pushed onto the queue of ``MOVE`` edges, and those pushed onto the queue of
    the other edges, each come in increasing order, and the cheaper head of the two is the
    next state (a stale entry, reached cheaper since, is skipped)."""
    n = table.shape[0] - 1
    cap = 3 * n + 8
    q_state = np.empty((2, cap), dtype=np.int64)
    q_cost = np.empty((2, cap), dtype=np.int64)
    for k in range(bounds.shape[0] - 1):
        row = out[k]
        head = np.zeros(2, dtype=np.int64)
        tail = np.zeros(2, dtype=np.int64)
        for i in range(bounds[k], bounds[k + 1]):
            s = sources[i]
            row[s] = 0
            q_state[0, tail[0]] = s
            q_cost[0, tail[0]] = 0
            tail[0] += 1
        while head[0] < tail[0] or head[1] < tail[1]:
            q = 0
            if head[0] == tail[0] or (head[1] < tail[1]
                                      and q_cost[1, head[1]] < q_cost[0, head[0]]):
                q = 1
            v = q_state[q, head[q]]
            d = q_cost[q, head[q]]
            head[q] += 1
            if d > row[v]:
                continue
            for j in range(3):
                u = table[v, j]
                if u >= n:
                    continue
                step = MOVE if j < 2 else forward[u]
                nd = d + step
                if row[u] < 0 or nd < row[u]:
                    row[u] = nd
                    p = 0 if step == MOVE else 1
                    q_state[p, tail[p]] = u
                    q_cost[p, tail[p]] = nd
                    tail[p] += 1


def guided_tables(grid: Grid, goals: Sequence[int], forward: npt.NDArray[np.int32]
                  ) -> npt.NDArray[np.int32]:
    """``out[k, 4 * cell + heading]``: the cheapest cost from that state to standing on cell
    ``goals[k]`` (flat ids, any heading) when a turn costs :data:`MOVE` and the forward move
    of state u ``forward[u]`` (:func:`crisscross`); -1 if unreachable. With every forward cost
    :data:`MOVE` it is :data:`MOVE` times the exact timesteps."""
    if forward.shape != (4 * grid.size,):
        raise ValueError(f"a guidance of {forward.shape[0]} states for a map of "
                         f"{4 * grid.size}")
    if np.unique(forward[forward != MOVE]).size > 1:
        raise ValueError(f"a guidance has two forward costs at most, {MOVE} and one other")
    free = grid.free.ravel()
    for g in goals:
        if not 0 <= g < grid.size or not free[g]:
            raise ValueError(f"goal {g} is not a free cell of {grid!r}")
    out = np.full((len(goals), 4 * grid.size), -1, dtype=np.int32)
    if goals:
        flat = np.array([4 * g + h for g in goals for h in range(4)], dtype=np.int64)
        bounds = np.arange(0, 4 * len(goals) + 1, 4, dtype=np.int64)
        _two_queue_groups(turning_predecessor_table(grid), forward.astype(np.int32), flat,
                         bounds, out)
    return out
