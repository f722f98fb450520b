"""The task API's messages (pydantic): what a warehouse system sends and what it is shown.

Cells are ``[x, y]`` (column, row) as everywhere in fleetgate. Every time is on one clock,
:data:`CLOCK`: ms of the shift (``now_ms`` in every list says where it stands), deadlines too;
each ``*_ms`` has an ``*_at`` beside it, the same instant as a wall-clock time (ISO 8601, UTC).
Every limit a stranger could abuse is bounded here: batch size, errands per task, key length,
numbers.
"""

from __future__ import annotations

from collections.abc import Callable
from datetime import UTC, datetime
from typing import Annotated, Literal

from pydantic import BaseModel, ConfigDict, Field, WithJsonSchema

from gateway.execution.lifelong.tasks import Task as PoolTask
from gateway.execution.lifelong.tasks import TaskEvent, TaskState
from gateway.planning.grid import Grid

MAX_BATCH = 1000
"""Tasks in one submission."""
MAX_ERRANDS = 32
"""Errand cells in one task."""
MAX_KEY_CHARS = 128
"""Characters of an idempotency key (printable ASCII)."""
MAX_LIST = 1000
"""Tasks in one page of ``GET /tasks``."""
MAX_BODY_BYTES = 256 * 1024
"""Bytes of a request body."""
CLOCK = ("every *_ms is ms of the shift's clock: 0 is the shift's start, and what happens "
         "before it (a task submitted before the robots are there) happens at 0; deadline_ms "
         "too. Each *_at is the same instant on the wall clock (ISO 8601, UTC: the shift's "
         "start plus the ms at the shift's speed, 1 outside demos), null while the shift has "
         "not started")
"""The task API's one clock, as its document says it."""

WallTime = Callable[[float], str | None]
"""Shift ms -> the wall-clock time of that instant (ISO 8601, UTC), None before the start."""


def iso_utc(wall_s: float) -> str:
    """A wall-clock time (POSIX seconds) as ISO 8601 in UTC, to the millisecond."""
    return datetime.fromtimestamp(wall_s, UTC).isoformat(timespec="milliseconds") \
        .replace("+00:00", "Z")

MAX_COORDINATE = 1_000_000
Coordinate = Annotated[int, Field(ge=0, le=MAX_COORDINATE)]
Cell = Annotated[tuple[Coordinate, Coordinate], WithJsonSchema({
    "type": "array", "minItems": 2, "maxItems": 2,
    "items": {"type": "integer", "minimum": 0, "maximum": MAX_COORDINATE}})]
"""``[x, y]``. Its JSON schema says "two integers" without ``prefixItems`` (the same
values: both items have one schema), which every OpenAPI tool reads."""
KEY_PATTERN = r"^[!-~]+$"
"""An idempotency key: printable ASCII, no spaces."""
Key = Annotated[str, Field(min_length=1, max_length=MAX_KEY_CHARS, pattern=KEY_PATTERN)]
Ms = Annotated[float, Field(ge=0, le=1e15, allow_inf_nan=False)]


class _Model(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)


class TaskSpec(_Model):
    """One task: errand cells in order, a priority (higher first) and a deadline (earlier
    first among equal priorities), both optional."""

    errands: list[Cell] = Field(min_length=1, max_length=MAX_ERRANDS)
    priority: int = Field(default=0, ge=-1000, le=1000)
    deadline_ms: Ms | None = None


class SubmitOne(TaskSpec):
    """``POST /tasks`` with one task; the key may also come as the ``Idempotency-Key``
    header (both: they must agree)."""

    idempotency_key: Key | None = None


class SubmitBatch(_Model):
    """``POST /tasks`` with a batch of tasks (accepted or refused as a whole)."""

    tasks: list[TaskSpec] = Field(min_length=1, max_length=MAX_BATCH)
    idempotency_key: Key | None = None


class TaskView(_Model):
    """A task as the API shows it (times: ms of the shift's clock, and the same instants on
    the wall clock; null: not yet)."""

    id: int
    state: TaskState
    robot: int | None
    """The robot doing it (assigned or started), else null."""
    errands: list[Cell]
    errands_done: int
    priority: int
    deadline_ms: float | None
    deadline_at: str | None
    idempotency_key: str | None
    submitted_ms: float
    """When it was submitted (0: before the shift started)."""
    submitted_at: str | None
    assigned_ms: float | None
    """When it was last given to a robot."""
    assigned_at: str | None
    errand_ms: list[float]
    """When each errand done so far was done."""
    errand_at: list[str | None]
    finished_ms: float | None
    finished_at: str | None
    cancelled_ms: float | None
    cancelled_at: str | None


class SubmitResponse(_Model):
    """The answer to ``POST /tasks``: 201 with the new tasks, or 200 with the same ones for a
    retried request (same idempotency key and body)."""

    created: bool
    tasks: list[TaskView]


class TaskList(_Model):
    """A page of ``GET /tasks`` in id order; ``next_after`` continues it (null: the end)."""

    now_ms: float
    """The shift's clock now (0 before its start)."""
    now_at: str | None
    tasks: list[TaskView]
    next_after: int | None
    counts: dict[TaskState, int]
    """Kept tasks per state (all of them, not only this page)."""
    last_event: int
    """The sequence number of the latest event: ``GET /tasks/events?after=`` it continues
    from this page without a gap."""


class TaskEventView(_Model):
    """A change of a task's state (``GET /tasks/events``; ``seq`` is the SSE event id)."""

    seq: int
    task: int
    state: TaskState
    robot: int | None
    errands_done: int
    t_ms: float
    at: str | None


class ResetEvent(_Model):
    """The data of an ``event: reset`` of ``GET /tasks/events``: events were dropped (or the
    client's id is another shift's); the stream goes on with event ``first``."""

    first: int


class ApiError(_Model):
    """Every refusal: 4xx (or 503) with a precise one-line message."""

    error: str


class TaskAction(_Model):
    """``POST /tasks/{id}/pause`` and ``/resume`` answer with the task."""

    action: Literal["pause", "resume"]
    task: TaskView


def task_view(task: PoolTask, grid: Grid, wall: WallTime) -> TaskView:
    """What the API shows of a task of the pool (flat cells turned into ``[x, y]``, each time
    also as ``wall`` tells it)."""
    assigned = task.assigned_at if task.assigned_at >= 0 else None
    finished = task.finish_tick if task.state == "finished" else None
    cancelled = task.cancelled_at if task.state == "cancelled" else None

    def at(t: float | None) -> str | None:
        return None if t is None else wall(t)

    return TaskView(
        id=task.id, state=task.state, robot=task.robot if task.robot >= 0 else None,
        errands=[grid.cell(c) for c in task.errands], errands_done=task.done,
        priority=task.priority, deadline_ms=task.deadline, deadline_at=at(task.deadline),
        idempotency_key=task.key, submitted_ms=task.submitted,
        submitted_at=wall(task.submitted), assigned_ms=assigned, assigned_at=at(assigned),
        errand_ms=list(task.errand_at), errand_at=[wall(t) for t in task.errand_at],
        finished_ms=finished, finished_at=at(finished), cancelled_ms=cancelled,
        cancelled_at=at(cancelled))


def event_view(event: TaskEvent, wall: WallTime) -> TaskEventView:
    """What the API shows of an event of the pool."""
    return TaskEventView(seq=event.seq, task=event.task, state=event.state,
                         robot=event.robot if event.robot >= 0 else None,
                         errands_done=event.done, t_ms=event.t, at=wall(event.t))
