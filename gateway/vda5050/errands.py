"""A lifelong shift's errands as VDA 5050 ``pick`` / ``drop`` actions (blocking HARD).

The lifelong executor's errand book marks, per robot, the count of finished actions at which
it stands on an errand cell (:class:`gateway.execution.lifelong.errands.ErrandBook`). For a
vehicle, the action that brings it there ends on a node carrying the errand's action: the
action is finished when that node action is, and the errand with it. The last errand of a task
is a ``drop``, the others ``pick``.

A marker can also come after the node it belongs to went to the vehicle (the robot already
stands on the errand cell when its task is planned, or the plan window that reaches it was
adopted after the action was released): then the errand is an action on the edge of the
vehicle's next action (HARD: done before it drives on). :meth:`ShiftErrands.marker` hears of
every marker as the book appends it, so none is missed.
"""

from __future__ import annotations

import re
from typing import TYPE_CHECKING, Literal

from gateway.execution.lifelong.tasks import TaskError
from protocol.messages import Action, parse_action_id
from protocol.vda5050.master import DEPART, Errand

if TYPE_CHECKING:
    from gateway.execution.lifelong.executor import LifelongExecutor
    from gateway.server.engine import Engine


_ERRAND_ID = re.compile(r"^(?:pick|drop)-t(\d+)\.\d+(?:" + re.escape(DEPART) + ")?$")


def errand_task(errand: str) -> int | None:
    """The task id in an errand's ``actionId`` (``pick-t<task>.<index>``), else None."""
    m = _ERRAND_ID.match(errand)
    return int(m[1]) if m else None


def give_up_failed(engine: Engine, errand: str) -> str | None:
    """A vehicle's pick or drop ``errand`` FAILED: the task is cancelled as the task API
    cancels it (``DELETE /tasks/<id>``: a task none of whose errands is done, journaled, its
    event on the stream; its robot finds it gone and takes another), and None is returned.
    A task with an errand done (a failed drop: the load is on the vehicle) cannot be
    cancelled: why not is returned, and the vehicle's action stays blocked for an operator.
    Call in the owner task."""
    task_id = errand_task(errand)
    shift = engine.lifelong
    if task_id is None or shift is None:
        return f"{errand} is no errand of this shift"
    try:
        shift.executor.pool.cancel(task_id, engine.now_ms())
    except TaskError as exc:
        return str(exc)
    return None


class ShiftErrands:
    """The errands of the vehicles ``robots`` in the engine's lifelong shift."""

    def __init__(self, engine: Engine, robots: set[int]) -> None:
        self.engine = engine
        self.robots = robots
        self._released: dict[int, int] = {}
        """Per vehicle, the highest action number released to it."""
        self._pending: dict[int, list[Errand]] = {}
        """Per vehicle, errands for the edge of its next action."""
        self._book: object = None

    def _executor(self) -> LifelongExecutor | None:
        shift = self.engine.lifelong
        if shift is None:
            return None
        executor = shift.executor
        if executor.book is not self._book:  # a new shift (or the first call)
            self._book = executor.book
            executor.book.on_marker = self.marker
        return executor

    def __call__(self, action: Action) -> list[Errand]:
        """The errands of ``action`` as it is released to its vehicle: the pending ones on its
        edge, its own on its end node."""
        executor = self._executor()
        if executor is None:
            return []
        _, robot, number = parse_action_id(action.action_id)
        self._released[robot] = max(self._released.get(robot, -1), number)
        out = self._pending.pop(robot, [])
        errand = self._errand(executor, robot, number + 1, on_edge=False)
        return out + ([errand] if errand is not None else [])

    def marker(self, robot: int, count: int, task_id: int) -> None:
        """The book appended a marker: an errand whose node already went to the vehicle
        becomes an errand on the edge of the vehicle's next action."""
        executor = self._executor()
        if executor is None or robot not in self.robots:
            return
        if count - 1 <= self._released.get(robot, -1):
            errand = self._errand(executor, robot, count, on_edge=True)
            if errand is not None:
                self._pending.setdefault(robot, []).append(errand)

    @staticmethod
    def _errand(executor: LifelongExecutor, robot: int, count: int, *,
                on_edge: bool) -> Errand | None:
        """The errand of the robot's (last) marker at ``count``, if any."""
        found: tuple[int, int] | None = None
        earlier: dict[int, int] = {}
        for at, task_id in executor.book.markers[robot]:
            if at > count:
                break
            if at == count:
                found = (task_id, earlier.get(task_id, 0))
            earlier[task_id] = earlier.get(task_id, 0) + 1
        if found is None:
            return None
        task_id, before = found
        task = executor.pool.tasks.get(task_id)
        if task is None:
            return None
        index = task.done + before
        kind: Literal["pick", "drop"] = "drop" if index >= len(task.errands) - 1 else "pick"
        return Errand(kind, f"{kind}-t{task_id}.{index}" + (DEPART if on_edge else ""),
                      f"task-{task_id}", on_edge)
