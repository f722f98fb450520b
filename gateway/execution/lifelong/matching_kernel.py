"""Compiled greedy matching of robots to tasks (numba): the kernel behind the schedulers of
:mod:`gateway.execution.lifelong.tasks` at warehouse scale.

Tasks that start on the same cell form a group and share a row of distances, so the cost of
robot r for task t is ``by_group[column[t], r] + extra[t]`` (``extra``: the task's length,
aging and urgency class). Within a group every robot ranks the tasks alike, by ``(extra[t],
t)``, and the group's tasks rank the robots alike, by ``(distance, r)``: the group's cheapest
pair is its first task not taken yet (its head) with its nearest robot not taken yet. The
greedy matching (pairs in increasing ``(cost, robot, task)``, each robot and task once) is a
heap of the groups keyed by that pair: a key only rises (robots are taken), so a popped group
whose robot is still free has the least pair of all, else it moves on to its next robot. Each
group keeps a sorted list of its :data:`NEAREST` nearest robots, built again from the robots
left when used up. The work is robots x groups to build the lists, plus the pairs; never a
robots x tasks matrix (10,000 robots x 15,000 tasks at each planning call of the
competition's warehouse), and robots that want the same task cost nothing more (the robots'
view, a heap of robots, rescans every robot that loses a popular task). Compiled with numba
for the reasons of :mod:`gateway.planning.bfs_kernel`.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt
from numba import njit

NEAREST = 32
"""Robots each group keeps in its sorted list (the same pairs for any value)."""


@njit(cache=True, nogil=True)
def _before(c: int, r: int, t: int, c2: int, r2: int, t2: int) -> bool:
    return c < c2 or (c == c2 and (r < r2 or (r == r2 and t < t2)))


@njit(cache=True, nogil=True)
def _nearest(u: int, by_group: npt.NDArray[np.int32], taken: npt.NDArray[np.bool_],
             unreachable: int, near: npt.NDArray[np.int64],
             count: npt.NDArray[np.int64]) -> None:
    """Fill ``near[u]`` with group u's nearest robots not taken, sorted by (distance,
    robot); ``count[u]`` of them."""
    cap = near.shape[1]
    n = 0
    dist = np.empty(cap, dtype=np.int64)
    for r in range(by_group.shape[1]):
        if taken[r]:
            continue
        d = by_group[u, r]
        c = d if d >= 0 else unreachable
        if n == cap and c >= dist[n - 1]:  # robots come in increasing order: ties lose
            continue
        i = n if n < cap else cap - 1
        while i > 0 and c < dist[i - 1]:
            dist[i] = dist[i - 1]
            near[u, i] = near[u, i - 1]
            i -= 1
        dist[i] = c
        near[u, i] = r
        if n < cap:
            n += 1
    count[u] = n


@njit(cache=True, nogil=True)
def _less(u: int, v: int, gc: npt.NDArray[np.int64], gr: npt.NDArray[np.int64],
          gt: npt.NDArray[np.int64]) -> bool:
    return _before(gc[u], gr[u], gt[u], gc[v], gr[v], gt[v])


@njit(cache=True, nogil=True)
def _sift_down(heap: npt.NDArray[np.int64], size: int, gc: npt.NDArray[np.int64],
               gr: npt.NDArray[np.int64], gt: npt.NDArray[np.int64]) -> None:
    i = 0
    while True:
        low = i
        for child in (2 * i + 1, 2 * i + 2):
            if child < size and _less(heap[child], heap[low], gc, gr, gt):
                low = child
        if low == i:
            return
        heap[i], heap[low] = heap[low], heap[i]
        i = low


@njit(cache=True, nogil=True)
def greedy_groups(by_group: npt.NDArray[np.int32], column: npt.NDArray[np.int64],
                  extra: npt.NDArray[np.int64], unreachable: int, nearest: int = NEAREST
                  ) -> tuple[npt.NDArray[np.int64], npt.NDArray[np.int64]]:
    """The greedy matching of robots (columns of ``by_group``) to tasks: pairs in increasing
    ``(cost, robot, task)``, each robot and task once, where robot r's cost for task t is
    ``by_group[column[t], r] + extra[t]``, with ``unreachable`` for a negative distance
    (``by_group`` is best C-contiguous: its rows are scanned). Returns the matched robots in
    the order matched and their tasks (as many pairs as the fewer of robots and tasks).
    ``nearest``: see :data:`NEAREST`."""
    n_groups, n_rows = by_group.shape
    n_tasks = column.shape[0]
    left = min(n_rows, n_tasks)
    robots = np.empty(left, dtype=np.int64)
    tasks = np.empty(left, dtype=np.int64)
    if left == 0:
        return robots, tasks
    by_extra = np.argsort(extra, kind="mergesort")  # ties: lower task first
    order = by_extra[np.argsort(column[by_extra], kind="mergesort")]
    end = np.zeros(n_groups, dtype=np.int64)
    for t in range(n_tasks):
        end[column[t]] += 1
    head = np.empty(n_groups, dtype=np.int64)
    total = 0
    for u in range(n_groups):
        head[u] = total
        total += end[u]
        end[u] = total
    taken = np.zeros(n_rows, dtype=np.bool_)
    near = np.empty((n_groups, nearest), dtype=np.int64)
    count = np.zeros(n_groups, dtype=np.int64)
    ptr = np.zeros(n_groups, dtype=np.int64)
    gc = np.zeros(n_groups, dtype=np.int64)  # each group's key: cost, robot, task
    gr = np.zeros(n_groups, dtype=np.int64)
    gt = np.zeros(n_groups, dtype=np.int64)
    heap = np.empty(n_groups, dtype=np.int64)
    size = 0
    for u in range(n_groups):
        if head[u] < end[u]:
            _nearest(u, by_group, taken, unreachable, near, count)
            r = near[u, 0]
            t = order[head[u]]
            d = by_group[u, r]
            gc[u], gr[u], gt[u] = (d if d >= 0 else unreachable) + extra[t], r, t
            heap[size] = u
            size += 1
    # a sorted array is a heap
    keyed = np.argsort(gt[heap[:size]], kind="mergesort")
    keyed = keyed[np.argsort(gr[heap[:size]][keyed], kind="mergesort")]
    keyed = keyed[np.argsort(gc[heap[:size]][keyed], kind="mergesort")]
    heap[:size] = heap[:size][keyed]
    k = 0
    while k < left:
        u = heap[0]
        if not taken[gr[u]]:
            r, t = gr[u], gt[u]
            taken[r] = True
            robots[k] = r
            tasks[k] = t
            k += 1
            head[u] += 1
            if head[u] == end[u] or k == left:  # no task left in the group
                size -= 1
                heap[0] = heap[size]
                _sift_down(heap, size, gc, gr, gt)
                continue
        p = ptr[u]  # the group's nearest robot not taken, its cheapest pair now
        while p < count[u] and taken[near[u, p]]:
            p += 1
        if p == count[u]:
            _nearest(u, by_group, taken, unreachable, near, count)
            p = 0
        ptr[u] = p
        r = near[u, p]
        t = order[head[u]]
        d = by_group[u, r]
        gc[u], gr[u], gt[u] = (d if d >= 0 else unreachable) + extra[t], r, t
        _sift_down(heap, size, gc, gr, gt)
    return robots, tasks
