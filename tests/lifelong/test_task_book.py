"""The task book: submissions with idempotency keys, priorities, cancel, pause, the events.

Properties are checked against an independent oracle: the state each task's events spell
out, replayed from the event stream alone."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import pytest
from hypothesis import settings
from hypothesis import strategies as st
from hypothesis.stateful import RuleBasedStateMachine, invariant, precondition, rule

from gateway.execution.lifelong.tasks import (
    NewTask,
    TaskConflict,
    TaskError,
    TaskNotFound,
    TaskPool,
    shortest_first,
)


def line(cells: Sequence[int], targets: Sequence[int]) -> np.ndarray:
    return np.abs(np.subtract.outer(np.asarray(cells), np.asarray(targets)))


def external(reveal: int = 4, keep: int = 1000) -> TaskPool:
    return TaskPool((), reveal, leg=lambda a, b: abs(a - b), keep=keep)


def test_submit_reveals_and_a_retry_creates_nothing() -> None:
    pool = external(reveal=2)
    ids, new = pool.submit([NewTask((5, 9)), NewTask((7,)), NewTask((1,))], now=10, key="k1")
    assert (ids, new) == ([0, 1, 2], True)
    assert sorted(pool.open) == [0, 1]  # two revealed, one waits
    again, new = pool.submit([NewTask((5, 9)), NewTask((7,)), NewTask((1,))], now=11, key="k1")
    assert (again, new) == ([0, 1, 2], False) and pool.next_id == 3
    with pytest.raises(TaskConflict, match=r"key 'k1' was used for a different request "
                                           r"\(tasks 0, 1, 2\)"):
        pool.submit([NewTask((5, 9))], now=12, key="k1")
    with pytest.raises(TaskError, match="task 1 of the submission has no errands"):
        pool.submit([NewTask((3,)), NewTask(())], now=12)
    assert [(e.task, e.state) for e in pool.events] == [(0, "queued"), (1, "queued"),
                                                        (2, "queued")]
    assert pool.task(2).submitted == 10 and pool.task(2).key == "k1"


def test_urgent_submission_takes_the_slot_of_a_waiting_one() -> None:
    pool = external(reveal=2)
    pool.submit([NewTask((1,)), NewTask((2,))], now=0)
    pool.assign(0, robot=0, now=1)
    pool.submit([NewTask((3,), priority=5)], now=2)
    assert sorted(pool.open) == [2]  # task 1 (open, less urgent) waits again; 0 is under way
    pool.submit([NewTask((4,), deadline=50.0), NewTask((6,), deadline=20.0)], now=3)
    assert sorted(pool.open) == [2] and pool.task(4).state == "queued"
    pool.errand_done(0, 5, robot=0)  # a slot frees: the earliest deadline first
    assert sorted(pool.open) == [2, 4]


def test_schedulers_take_the_most_urgent_first() -> None:
    pool = external(reveal=4)
    pool.submit([NewTask((10,)), NewTask((90,), priority=1), NewTask((50,), deadline=5.0)],
                now=0)
    free = [(0, 9), (1, 11)]
    # robot 0 at 9 would take task 0 (1 away) without priorities
    assert sorted(shortest_first(free, pool, line).values()) == [1, 2]
    assert shortest_first([(0, 60)], pool, line) == {0: 1}
    pool.cancel(1, now=1)
    assert shortest_first([(0, 9)], pool, line) == {0: 2}  # the deadline breaks the tie


def test_unreachable_urgent_task_does_not_block_a_reachable_one() -> None:
    pool = external()
    pool.submit([NewTask((10,)), NewTask((99,), priority=3)], now=0)

    def cut(cells: Sequence[int], targets: Sequence[int]) -> np.ndarray:
        out = line(cells, targets)
        out[:, [t == 99 for t in targets]] = -1
        return out

    assert shortest_first([(0, 9)], pool, cut) == {0: 0}


def test_reassignment_to_the_same_robot_makes_no_event() -> None:
    pool = external()
    pool.submit([NewTask((1, 2)), NewTask((3,))], now=0)
    pool.assign(0, 7, now=1)
    pool.assign(1, 8, now=1)
    n = len(pool.events)
    pool.release(0, now=2)
    pool.release(1, now=2)
    pool.assign(0, 7, now=2)  # the same robot again: nothing happened
    pool.settle(2)  # task 1 was not given back: it is queued again
    assert [(e.task, e.state, e.robot) for e in list(pool.events)[n:]] == [(1, "queued", -1)]
    assert pool.task(1).state == "queued"


def test_cancel_and_pause_refuse_started_tasks_precisely() -> None:
    pool = external()
    pool.submit([NewTask((1, 2)), NewTask((3,))], now=0)
    pool.assign(0, 4, now=1)
    pool.errand_done(0, 2, robot=4)
    with pytest.raises(TaskConflict, match=r"task 0 is started \(robot 4 has done 1 of its 2 "
                                           r"errands\): it cannot be cancelled"):
        pool.cancel(0, now=3)
    with pytest.raises(TaskConflict, match="cannot be paused"):
        pool.pause(0, now=3)
    assert pool.errand_done(0, 4, robot=4)
    with pytest.raises(TaskConflict, match="task 0 is finished: it cannot be cancelled"):
        pool.cancel(0, now=5)
    with pytest.raises(TaskNotFound, match="no task 9"):
        pool.cancel(9, now=5)
    assert pool.cancel(1, now=5).state == "cancelled"
    assert pool.cancel(1, now=6).cancelled_at == 5  # a retried cancel changes nothing


def test_a_withdrawn_task_ignores_its_old_robot() -> None:
    pool = external()
    pool.submit([NewTask((1,))], now=0)
    pool.assign(0, 3, now=1)
    pool.pause(0, now=2)
    assert 0 not in pool.tasks and pool.task(0).robot == -1
    assert pool.errand_done(0, 3, robot=3) is False  # robot 3 reaches the cell: ignored
    pool.resume(0, now=4)
    pool.assign(0, 5, now=5)
    assert pool.errand_done(0, 6, robot=3) is False  # a stale marker of robot 3
    assert pool.task(0).done == 0
    assert pool.errand_done(0, 7, robot=5) is True


def test_memory_is_bounded_and_old_tasks_say_so() -> None:
    pool = external(reveal=2, keep=3)
    for k in range(6):
        (tid,), _ = pool.submit([NewTask((k,))], now=k, key=f"key{k}")
        pool.cancel(tid, now=k)
    assert len(pool.book) == 3 and len(pool.events) == 3
    with pytest.raises(TaskNotFound, match="task 0 ended long ago"):
        pool.task(0)
    events, complete = pool.events_after(0)
    assert not complete and [e.seq for e in events] == [10, 11, 12]
    events, complete = pool.events_after(10)
    assert complete and [e.seq for e in events] == [11, 12]
    assert pool.submit([NewTask((5,))], now=9, key="key5") == ([5], False)
    assert pool.submit([NewTask((0,))], now=9, key="key0")[1]  # forgotten key: new task


def test_list_pool_cancel_reveals_the_next_list_task() -> None:
    pool = TaskPool([(1,), (2, 3)], reveal=2)
    pool.cancel(0, now=3)
    assert sorted(pool.tasks) == [1, 2] and pool.tasks[2].errands == (1,)


# ---------------------------------------------------------------------- properties
BODIES = st.lists(st.builds(NewTask, st.tuples(st.integers(0, 20)).map(tuple)
                            | st.lists(st.integers(0, 20), min_size=1, max_size=3).map(tuple),
                            st.integers(0, 2), st.none() | st.floats(0, 100)),
                  min_size=1, max_size=3)


class TaskBookMachine(RuleBasedStateMachine):
    """Random submissions (some retried under the same key), scheduling, releases, errands,
    cancels, pauses and resumes; the oracle is the event stream."""

    def __init__(self) -> None:
        super().__init__()
        self.pool = TaskPool((), reveal=3, keep=10_000)
        self.t = 0.0
        self.robots: dict[int, int] = {}  # robot -> task it does
        self.requests: dict[str, tuple[list[NewTask], list[int]]] = {}

    def tick(self) -> float:
        self.t += 1.0
        return self.t

    def mine(self, robot: int) -> int | None:
        """The task ``robot`` does, forgotten if the pool took it away (cancel, pause)."""
        task_id = self.robots.get(robot)
        if task_id is not None and (task_id not in self.pool.tasks
                                    or self.pool.tasks[task_id].robot != robot):
            del self.robots[robot]
            return None
        return task_id

    @rule(body=BODIES, key=st.none() | st.sampled_from(["a", "b", "c"]))
    def submit(self, body: list[NewTask], key: str | None) -> None:
        before = self.pool.next_id
        if key is not None and key in self.requests:
            old, ids = self.requests[key]
            if old != body:
                with pytest.raises(TaskConflict):
                    self.pool.submit(body, self.tick(), key)
                return
            assert self.pool.submit(body, self.tick(), key) == (ids, False)
            assert self.pool.next_id == before
            return
        ids, new = self.pool.submit(body, self.tick(), key)
        assert new and ids == list(range(before, before + len(body)))
        if key is not None:
            self.requests[key] = (body, ids)
        # the most urgent tasks are the revealed ones
        waiting = [t for t in self.pool.book.values() if t.state == "queued"
                   and t.id not in self.pool.tasks]
        for w in waiting:
            assert all(w.urgency >= o.urgency for o in self.pool.open.values())

    @rule(robot=st.integers(0, 3))
    def schedule(self, robot: int) -> None:
        if self.mine(robot) is not None or not self.pool.open:
            return
        chosen = shortest_first([(robot, robot * 5)], self.pool, line)
        for r, task_id in chosen.items():
            self.pool.assign(task_id, r, self.tick())
            self.robots[r] = task_id

    @rule(robot=st.integers(0, 3))
    def release(self, robot: int) -> None:
        task_id = self.mine(robot)
        if task_id is not None and not self.pool.tasks[task_id].done:
            self.pool.release(task_id, self.tick())
            del self.robots[robot]

    @rule(robot=st.integers(0, 3))
    def reach(self, robot: int) -> None:
        task_id = self.robots.get(robot)
        if task_id is None:
            return
        finished = self.pool.errand_done(task_id, self.tick(), robot)
        task = self.pool.task(task_id)
        if finished or task.robot != robot:  # done, or taken away meanwhile
            del self.robots[robot]

    @precondition(lambda self: self.pool.next_id > 0)
    @rule(data=st.data(), what=st.sampled_from(["cancel", "pause", "resume"]))
    def operator(self, data: st.DataObject, what: str) -> None:
        task_id = data.draw(st.integers(0, self.pool.next_id - 1))
        task = self.pool.task(task_id)
        refused = (what != "resume" and task.state in ("started", "finished")) or (
            what == "resume" and task.state in ("finished", "cancelled")) or (
            what == "pause" and task.state == "cancelled")
        if refused:
            with pytest.raises(TaskConflict):
                getattr(self.pool, what)(task_id, self.tick())
        else:
            getattr(self.pool, what)(task_id, self.tick())

    @rule()
    def settle(self) -> None:
        self.pool.settle(self.tick())

    @invariant()
    def the_events_tell_the_truth(self) -> None:
        pool = self.pool
        pool.settle(self.t)
        seen: dict[int, tuple[str, int, int]] = {}
        finished: set[int] = set()
        seqs = [e.seq for e in pool.events]
        assert seqs == list(range(1, len(seqs) + 1))
        assert [e.t for e in pool.events] == sorted(e.t for e in pool.events)
        for e in pool.events:
            prev = seen.get(e.task)
            assert prev is None or prev[0] not in ("finished", "cancelled"), \
                f"task {e.task} changed after it ended"
            if e.state == "assigned":
                assert prev is not None and prev[0] == "queued", f"{prev} -> assigned"
            if e.state == "finished":
                assert e.task not in finished
                finished.add(e.task)
            seen[e.task] = (e.state, e.robot, e.done)
        assert len(finished) == pool.finished
        for task_id, task in pool.book.items():
            assert seen[task_id] == (task.state, task.robot, task.done)
        # nobody does a cancelled, paused or ended task; the revealed ones are bounded
        assert set(pool.open) <= set(pool.tasks) and len(pool.tasks) <= pool.reveal
        for task in pool.tasks.values():
            assert task.state in ("queued", "assigned", "started")
            assert (task.id in pool.open) == (task.state == "queued")


    def teardown(self) -> None:
        """At the end of each run: :meth:`a_restart_rebuilds_the_book`."""
        self.a_restart_rebuilds_the_book()

    def a_restart_rebuilds_the_book(self) -> None:
        """A fresh pool fed the events (the journal's records) knows every task, finishes
        none again, and a retried submission still gets its ids."""
        live = self.pool
        again = TaskPool((), reveal=3, keep=10_000)
        for e in live.events:
            task = live.book[e.task]
            new = NewTask(task.errands, task.priority, task.deadline)
            again.restore(e, new if e.state == "queued" else None, task.key)
        again.restored(self.t)
        assert again.finished == live.finished and again.next_id == live.next_id
        for task_id, task in live.book.items():
            back = again.book[task_id]
            want = "queued" if task.state == "assigned" else task.state
            assert (back.state, back.done, back.errands) == (want, task.done, task.errands)
            if task.state == "started":
                assert back.robot == task.robot and task_id in again.tasks
            if task.state in ("finished", "cancelled"):
                assert not again.errand_done(task_id, self.t + 1)
        for key, (body, ids) in self.requests.items():
            assert again.submit(body, self.t + 1, key) == (ids, False)
        assert again.event_seq >= live.event_seq


TaskBookMachine.TestCase.settings = settings(max_examples=40, stateful_step_count=30,
                                             deadline=None)
test_task_book_properties = TaskBookMachine.TestCase
