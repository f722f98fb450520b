"""Task pool and schedulers, on a line of cells where distance is |a - b|."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from gateway.execution.tasks import TaskPool, greedy_nearest, min_cost, shortest_first


def line(cells: Sequence[int], targets: Sequence[int]) -> np.ndarray:
    return np.abs(np.subtract.outer(np.asarray(cells), np.asarray(targets)))


def test_pool_reveals_cycles_and_finishes() -> None:
    pool = TaskPool([(1,), (2, 3)], reveal=2)
    assert sorted(pool.open) == [0, 1]
    pool.assign(1, robot=7)
    assert not pool.errand_done(1, tick=4)
    assert pool.errand_done(1, tick=9)  # second errand: the task is done, task 2 revealed
    assert pool.finished == 1 and sorted(pool.tasks) == [0, 2]
    assert pool.tasks[2].errands == (1,) and pool.tasks[2].release_tick == 9


def test_schedulers() -> None:
    # tasks: id 0 starts at 10 (long: 10 -> 40), id 1 starts at 12 (short: 12 -> 13)
    pool = TaskPool([(10, 40), (12, 13)], reveal=2, leg=lambda a, b: abs(a - b))
    free = [(0, 9), (1, 11)]
    assert greedy_nearest(free, pool, line) == {0: 0, 1: 1}  # robot 0 first, nearest to it
    assert min_cost(free, pool, line) == {0: 0, 1: 1}  # pairs 9-10 and 11-12 cost 1 each
    # by distance plus length, robot 1 (cost 1 + 1) gets the short task first and robot 0
    # the long one; with one free robot it takes the short task although it is farther
    assert shortest_first(free, pool, line) == {1: 1, 0: 0}
    assert shortest_first([(0, 9)], pool, line) == {0: 1}
