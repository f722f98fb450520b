"""Task pool and schedulers, on a line of cells where distance is |a - b|."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import pytest

from gateway.execution.lifelong.tasks import TaskPool, greedy_nearest, min_cost, shortest_first


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


def test_released_task_goes_back_to_the_scheduler() -> None:
    pool = TaskPool([(10, 40), (12, 13)], reveal=2, leg=lambda a, b: abs(a - b))
    assert pool.tasks[0].length == -1  # lengths are computed when a scheduler asks
    assert shortest_first([(0, 9)], pool, line) == {0: 1}  # 3 + 1 < 1 + 30
    assert pool.tasks[1].length == 1 and pool.tasks[0].length == 30
    pool.assign(1, 0)
    pool.release(1)  # not started: another robot may take it
    assert pool.tasks[1].robot == -1 and 1 in pool.open
    assert shortest_first([(0, 39), (5, 11)], pool, line) == {5: 1, 0: 0}  # 1 + 1, 29 + 30
    pool.assign(1, 5)
    assert pool.errand_done(1, tick=3) is False
    with pytest.raises(ValueError, match="already started"):
        pool.release(1)  # its first errand is done
