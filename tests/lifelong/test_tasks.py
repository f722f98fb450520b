"""Task pool and schedulers, on a line of cells where distance is |a - b|."""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from gateway.execution.lifelong.errands import ErrandBook
from gateway.execution.lifelong.tasks import (
    SCHEDULERS,
    NewTask,
    TaskPool,
    shortest_first,
    wait_percentiles,
)


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
    free = [(0, 9), (1, 12)]
    # the cheapest pair first: robot 1 on the short task's first errand (0 + 1), then robot 0
    # on the long one (1 + 30)
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


def test_an_overdue_task_goes_before_cheaper_ones_of_its_priority() -> None:
    # a long task (10 -> 40) submitted at 0, a short one (12 -> 13) at 25: shortest_first
    # passes the long one over as long as short ones keep coming, unless it waited max_wait
    for bound, want in ((None, 1), (50.0, 1), (30.0, 0)):
        pool = TaskPool([], reveal=2, leg=lambda a, b: abs(a - b), max_wait=bound)
        pool.submit([NewTask((10, 40))], now=0.0)
        pool.submit([NewTask((12, 13))], now=25.0)
        pool.settle(30.0)
        assert pool.overdue(pool.tasks[0]) is (want == 0)
        assert not pool.overdue(pool.tasks[1])
        assert shortest_first([(0, 11)], pool, line) == {0: want}


def test_priority_still_beats_an_overdue_task() -> None:
    pool = TaskPool([], reveal=2, leg=lambda a, b: abs(a - b), max_wait=10.0)
    old, _ = pool.submit([NewTask((10, 40))], now=0.0)
    urgent, _ = pool.submit([NewTask((30, 90), priority=1)], now=20.0)
    pool.settle(25.0)  # the old one is overdue, the urgent one is not
    assert shortest_first([(0, 11)], pool, line) == {0: urgent[0]}
    # the urgent task's pairs first: robot 1 is nearer to its first errand (18 against 19)
    assert shortest_first([(0, 11), (1, 12)], pool, line) == {1: urgent[0], 0: old[0]}


def test_overdue_tasks_go_longest_waiting_first() -> None:
    pool = TaskPool([], reveal=3, leg=lambda a, b: abs(a - b), max_wait=10.0)
    far, _ = pool.submit([NewTask((90,))], now=0.0)
    near, _ = pool.submit([NewTask((12,))], now=5.0)
    pool.submit([NewTask((11,))], now=19.0)
    pool.settle(20.0)  # far and near are overdue, far the longest; fresh is not
    assert shortest_first([(0, 11)], pool, line) == {0: far[0]}
    assert shortest_first([(0, 11), (1, 10)], pool, line) == {0: far[0], 1: near[0]}


def test_wait_percentiles_by_nearest_rank() -> None:
    assert wait_percentiles([]) == {"p50": 0.0, "p90": 0.0, "p99": 0.0, "max": 0.0}
    waits = [float(w) for w in range(1, 101)]  # 1 .. 100
    assert wait_percentiles(waits[::-1]) == {"p50": 50.0, "p90": 90.0, "p99": 99.0,
                                             "max": 100.0}
    pool = TaskPool([], reveal=1, max_wait=None)
    a, _ = pool.submit([NewTask((3,))], now=2.0)
    pool.submit([NewTask((4,))], now=3.0)  # not revealed: it waits in the backlog
    c, _ = pool.submit([NewTask((5,))], now=3.0)
    pool.assign(a[0], robot=0, now=9.0)
    pool.cancel(c[0], now=4.0)
    assert sorted(pool.waits(now=10.0)) == [7.0, 7.0]  # a: 9 - 2; b: queued since 3


@settings(max_examples=60, deadline=None)
@given(st.lists(st.tuples(st.integers(0, 60), st.integers(0, 60)), min_size=1, max_size=30),
       st.integers(1, 4), st.integers(1, 8), st.integers(1, 20),
       st.sampled_from(sorted(SCHEDULERS)))
def test_the_bound_holds_under_a_stream_of_cheaper_tasks(
        errands: list[tuple[int, int]], free_per_step: int, reveal: int, bound: int,
        name: str) -> None:
    """Robots come free ``free_per_step`` at a time at every step (they finish a task in one
    step); however cheap the other tasks, a task waits at most ``bound`` plus the steps to
    serve the tasks overdue before it: ceil(reveal / free_per_step)."""
    pool = TaskPool(errands, reveal=reveal, leg=lambda a, b: abs(a - b), max_wait=bound)
    scheduler = SCHEDULERS[name]
    robots = [(r, 30) for r in range(free_per_step)]
    for step in range(1, 120):
        pool.settle(float(step))
        for robot, task_id in scheduler(robots, pool, line).items():
            pool.assign(task_id, robot, now=float(step))
            for _ in pool.tasks[task_id].errands:
                pool.errand_done(task_id, float(step))
    limit = bound + math.ceil(reveal / free_per_step)
    assert max(pool.waits(now=120.0)) <= limit


def test_a_waiting_task_ages_before_it_is_overdue() -> None:
    # robot at 0; first errands: A at 50 (submitted at 0), B at 10 and C at 90 (both at 50):
    # costs 50, 10, 90, span 80. From half the bound (100) on, A costs up to the span less:
    # at 60 it waited 0.6 of it (16 less: 34, B still cheaper), at 90 0.9 (64 less: -14)
    for now, bound, want in ((60.0, 100.0, "B"), (90.0, 100.0, "A"), (90.0, None, "B")):
        pool = TaskPool([], reveal=3, max_wait=bound)
        ids = {name: pool.submit([NewTask((cell,))], now=t)[0][0]
               for name, cell, t in (("A", 50, 0.0), ("B", 10, 50.0), ("C", 90, 50.0))}
        pool.settle(now)
        assert not pool.overdue(pool.tasks[ids["A"]])
        assert shortest_first([(0, 0)], pool, line) == {0: ids[want]}


@settings(max_examples=60, deadline=None)
@given(st.lists(st.tuples(st.integers(0, 3), st.integers(0, 9)), min_size=1, max_size=30),
       st.integers(1, 4), st.data())
def test_a_station_cap_offers_each_first_cell_what_its_queue_leaves(
        errands: list[tuple[int, int]], cap: int, data: st.DataObject) -> None:
    """Per first-errand cell: offered = min(open there, cap - robots on their way there), the
    shortest first; robots past the first errand do not count; no cap offers all open tasks."""
    leg = lambda a, b: abs(a - b)  # noqa: E731
    pool = TaskPool(errands, reveal=len(errands), leg=leg, station_cap=cap)
    plain = TaskPool(errands, reveal=len(errands), leg=leg)
    assert plain.offered().tolist() == sorted(plain.open)
    given_to = data.draw(st.lists(st.sampled_from(sorted(pool.open)), unique=True))
    for robot, task_id in enumerate(given_to):
        pool.assign(task_id, robot)
    started = data.draw(st.lists(st.sampled_from(given_to), unique=True)) if given_to else []
    for task_id in started:
        pool.errand_done(task_id, tick=1)
    offered = pool.offered().tolist()
    assert offered == sorted(offered) and set(offered) <= set(pool.open)
    for cell in {e[0] for e in errands}:
        here = [t for t in pool.open.values() if t.errands[0] == cell]
        busy = sum(1 for t in pool.tasks.values()
                   if t.robot >= 0 and t.done == 0 and t.errands[0] == cell)
        got = [t for t in here if t.id in offered]
        assert len(got) == max(0, min(len(here), cap - busy))
        if got:  # the shortest (then the lowest ids) of the cell's open tasks
            key = [(pool.length(t), t.id) for t in here]
            assert sorted((pool.length(t), t.id) for t in got) == sorted(key)[: len(got)]


def test_schedulers_hand_out_only_offered_tasks() -> None:
    # three tasks from cell 0, one from cell 5; a cap of 1 offers one of cell 0's
    pool = TaskPool([(0, 9), (0, 1), (0, 4), (5, 6)], reveal=4, leg=lambda a, b: abs(a - b),
                    station_cap=1)
    free = [(0, 0), (1, 0), (2, 0)]
    for scheduler in SCHEDULERS.values():
        got = scheduler(free, pool, line)
        assert sorted(got.values()) == [1, 3]  # the short one of cell 0, and cell 5's


def test_retracted_errands_go_back_to_the_plan_view() -> None:
    """Robot 0's committed plan reaches both errands of task 0 (after its 2nd and 4th action)
    and the first of task 1 (6th); its actions beyond the 3rd are taken back: the markers
    beyond go, task 0 is planned again from its second errand, task 1 goes back to the pool;
    then the robot does its 2nd action and the first errand is done as planned."""
    pool = TaskPool([(10, 12), (20, 21), (30,)], reveal=3)
    book = ErrandBook(pool, 1)
    pool.assign(0, 0)
    book.plan_task[0] = 0
    states = [[s] for s in (9, 10, 11, 12)]  # one action a step, errands after steps 1 and 3
    book.register([1], states, [[1, 3]], book.planned([[1, 3]]))
    assert book.plan_task == [-1]  # the plan reaches the whole task
    pool.assign(1, 0)
    book.plan_task[0] = 1
    book.register([4], [[12], [19], [20]], [[2]], book.planned([[2]]))
    assert [m for m, _ in book.markers[0]] == [2, 4, 6]
    book.retract([3], now=5)
    assert list(book.markers[0]) == [(2, 0)]
    assert (book.plan_task, book.plan_idx) == ([0], [1])
    assert 1 in pool.open and pool.tasks[1].robot == -1
    assert book.reach(0, 2) == [0] and book.goals() == [(12,)]


def test_a_large_first_matching_is_spread_over_calls(monkeypatch: pytest.MonkeyPatch) -> None:
    # 6 robots, 6 tasks on 6 cells: 36 distances, over a bound of 12, so a call matches the
    # first 2 robots (12 // 6) and the others wait for the next calls, in order: then 4
    # robots for 4 tasks, 16 over 12, so 3 (12 // 4), then the last one
    import gateway.execution.lifelong.tasks as tasks

    monkeypatch.setattr(tasks, "MATCH_ENTRIES", 12)
    pool = TaskPool([(10 * i, 10 * i + 1) for i in range(6)], reveal=6,
                    leg=lambda a, b: abs(a - b))
    book = ErrandBook(pool, 6)
    seen: list[int] = []

    def counted(cells: Sequence[int], targets: Sequence[int]) -> np.ndarray:
        seen.append(len(cells) * len(targets))
        return line(cells, targets)

    cells = [50, 40, 30, 20, 10, 0]
    calls = [sorted(r for r, _ in book.schedule(cells, shortest_first, counted, now))
             for now in range(4)]
    assert calls == [[0, 1], [2, 3, 4], [5], []]
    assert seen == [12, 12, 1]
    assert book.plan_task == [5, 4, 3, 2, 1, 0]  # each on the task on its own cell
    # under the bound the whole matching is one call (every fleet of the shared problems)
    monkeypatch.setattr(tasks, "MATCH_ENTRIES", 36)
    pool = TaskPool([(10 * i, 10 * i + 1) for i in range(6)], reveal=6,
                    leg=lambda a, b: abs(a - b))
    assert len(shortest_first(list(enumerate(cells)), pool, line)) == 6


def test_a_many_robot_first_call_does_not_match_every_robot() -> None:
    # 3,000 robots for 4,000 tasks on as many cells: 12 million distances, over the bound, so
    # the first call matches the first MATCH_ENTRIES // 4,000 robots (2,000) and no more
    from gateway.execution.lifelong.tasks import MATCH_ENTRIES

    pool = TaskPool([(2 * i, 2 * i + 1) for i in range(4000)], reveal=4000,
                    leg=lambda a, b: abs(a - b))
    book = ErrandBook(pool, 3000)
    pairs = book.schedule([2 * r for r in range(3000)], shortest_first, line, 0)
    assert sorted(r for r, _ in pairs) == list(range(MATCH_ENTRIES // 4000))
    assert all(pool.tasks[t].errands[0] == 2 * r for r, t in pairs)  # each on its own cell
