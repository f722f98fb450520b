"""The task API for a warehouse system (WMS), on the gateway's port, authenticated like the
operator (``Authorization: Bearer <operator token>``, or the GUI's login cookie with a
same-origin ``Origin`` for changes).

Routes (models: :mod:`gateway.server.task_api.models`; the document: ``GET /openapi.json``):

* ``POST /tasks``: one task or a batch, with an idempotency key (``Idempotency-Key`` header or
  ``idempotency_key`` field): 201 with the new tasks, 200 with the same ones for a retry,
  409 if the key was used for a different request;
* ``GET /tasks``: a page of tasks in id order (``state``, ``robot``, ``after``, ``limit``);
* ``GET /tasks/{id}``; ``DELETE /tasks/{id}`` cancels a task not started yet (409 otherwise);
* ``POST /tasks/{id}/pause`` and ``/resume``: an operator holds a task back (never assigned
  while paused) and lets it go again;
* ``GET /tasks/events``: server-sent events, one per change of a task (``id`` is its sequence
  number); ``Last-Event-ID`` (or ``?after=``) resumes after a reconnect; a ``reset`` event
  says events were dropped meanwhile, or the id is one this gateway never gave (another
  shift's): re-read ``GET /tasks``.

Changes run in the engine's owner task (an :class:`~gateway.server.items.OwnerCall`: the single
writer), are journaled there (:mod:`gateway.server.runs.task_journal`) and are answered only after
the owner task committed the journal. Reads look at the pool between owner steps, so they see
only committed state. Refusals are 4xx with ``{"error": "<one line>"}``.
"""

from __future__ import annotations

import asyncio
import json
import re
from collections.abc import AsyncIterator, Callable
from typing import TYPE_CHECKING, Literal, Protocol, TypeVar, cast
from urllib.parse import parse_qs

from pydantic import ValidationError

from gateway.execution.lifelong.executor import LifelongMode
from gateway.execution.lifelong.tasks import (
    TASK_STATES,
    NewTask,
    Task,
    TaskConflict,
    TaskError,
    TaskNotFound,
    TaskPool,
    TaskState,
)
from gateway.server.items import Item, OwnerCall
from gateway.server.runs.lifelong import LifelongRun
from gateway.server.task_api.models import (
    MAX_LIST,
    SubmitBatch,
    SubmitOne,
    SubmitResponse,
    TaskAction,
    TaskList,
    TaskView,
    event_view,
    iso_utc,
    task_view,
)
from gateway.server.wire.auth import COOKIE, Authenticator, AuthError, cookie_value, origin_allowed
from gateway.server.wire.http_api import ApiRequest, ApiResponse, HttpError, json_answer
from protocol.codec import ProtocolError, check_text

if TYPE_CHECKING:
    from gateway.planning.grid import Grid

_TASK_PATH = re.compile(r"^/tasks/([^/]+)(/pause|/resume)?$")
KEEPALIVE_S = 15.0
"""A comment line on an idle event stream this often (proxies keep it open)."""
POLL_S = 0.1
"""How often an event stream looks for new events."""
MAX_STREAMS = 32
"""Event streams open at once."""
T = TypeVar("T")


def _first_error(exc: ValidationError) -> str:
    err = exc.errors(include_url=False)[0]
    where = ".".join(str(p) for p in err["loc"] if not str(p).startswith("function-"))
    return f"{where}: {err['msg']}" if where else str(err["msg"])


def _reset(first: int) -> bytes:
    """The ``reset`` event: the stream goes on with event ``first``; re-read the tasks."""
    return f"event: reset\ndata: {json.dumps({'first': first})}\n\n".encode()


class Owner(Protocol):
    """What the task API talks to: the owner task's queue, the present, and the shift (the
    gateway's engine provides them; the task API never touches the engine otherwise)."""

    queue: asyncio.Queue[Item]

    @property
    def lifelong(self) -> LifelongRun | None:
        """The shift (None: the gateway runs no shift)."""
        ...

    def now_ms(self) -> float:
        """The shift's present."""
        ...


def _pool(owner: Owner) -> TaskPool | None:
    """The shift's task pool (None: no shift)."""
    run = owner.lifelong
    return run.tasks if run is not None else None


class TaskApi:
    """Answers the task API's requests for one gateway (see the module doc)."""

    def __init__(self, owner: Owner, auth: Authenticator, *, tls: bool,
                 allowed_origins: list[str]) -> None:
        self._engine = owner
        self._auth = auth
        self._tls = tls
        self._origins = allowed_origins
        self.streams = 0
        """Event streams open now."""

    # ------------------------------------------------------------------ entry
    async def __call__(self, req: ApiRequest) -> ApiResponse:
        """The response to one request (HttpError for a refusal)."""
        self._authorize(req)
        pool = _pool(self._engine)
        if pool is None:
            raise HttpError(503, "no task pool: the gateway is not in lifelong mode")
        grid = self._grid()
        if req.method == "POST" and (req.path == "/tasks" or req.path.endswith("/resume")) \
                and self._ended():
            raise HttpError(409, "the shift has ended: no new task would run")
        if req.path == "/tasks":
            if req.method == "POST":
                return await self._submit(req, grid)
            if req.method == "GET":
                return self._list(req, pool, grid)
            raise HttpError(405, f"{req.method} /tasks: use GET or POST",
                            [("Allow", "GET, POST")])
        if req.path == "/tasks/events":
            if req.method != "GET":
                raise HttpError(405, "the event stream is read with GET", [("Allow", "GET")])
            return self._events(req, pool)
        m = _TASK_PATH.match(req.path)
        if m is None:
            raise HttpError(404, f"no route {req.path[:100]}")
        action = m.group(2)
        if action is not None and req.method != "POST":
            raise HttpError(405, f"{action[1:]} a task with POST", [("Allow", "POST")])
        if action is None and req.method not in ("GET", "DELETE"):
            raise HttpError(405, f"{req.method} /tasks/{{id}}: use GET or DELETE",
                            [("Allow", "GET, DELETE")])
        if not (m.group(1).isdigit() and len(m.group(1)) <= 18):
            raise HttpError(404, f"no task {m.group(1)[:40]!r}: a task id is a whole number")
        task_id = int(m.group(1))
        if action is not None:
            act: Literal["pause", "resume"] = "pause" if action == "/pause" else "resume"
            task = await self._change(lambda p, now: (p.pause if act == "pause"
                                                      else p.resume)(task_id, now))
            return json_answer(200, TaskAction(action=act, task=self._view(task, grid))
                               .model_dump(mode="json"))
        if req.method == "GET":
            return json_answer(200, self._view(self._found(pool, task_id), grid)
                               .model_dump(mode="json"))
        task = await self._change(lambda p, now: p.cancel(task_id, now))  # DELETE
        return json_answer(200, self._view(task, grid).model_dump(mode="json"))

    def now_ms(self) -> float:
        """The one clock of the task API: plan ms since the shift started, 0 before it (a
        task submitted before the start is submitted at 0)."""
        run = self._engine.lifelong
        return 0.0 if run is None else run.now_ms()

    def wall_time(self, t_ms: float) -> str | None:
        """The wall-clock time (ISO 8601, UTC) of shift time ``t_ms``: the shift's start plus
        the ms at its speed; None while it has not started."""
        run = self._engine.lifelong
        start = None if run is None else run.started
        return None if start is None else iso_utc(start.wall_start_s
                                                  + t_ms / 1000.0 / start.speed)

    def _view(self, task: Task, grid: Grid) -> TaskView:
        return task_view(task, grid, self.wall_time)

    def _grid(self) -> Grid:
        run = self._engine.lifelong
        assert run is not None
        return run.shift.grid

    def _ended(self) -> bool:
        """Whether the shift is stopping or over (robots take no new task)."""
        run = self._engine.lifelong
        assert run is not None
        return run.executor.mode in (LifelongMode.STOPPING, LifelongMode.DONE)

    def _authorize(self, req: ApiRequest) -> None:
        """An operator's token, or the GUI's login (same origin for changes); HttpError."""
        try:
            authorization = req.headers.get_all("Authorization")
            if len(authorization) > 1:
                raise AuthError(400, "Authorization header given more than once")
            if authorization:
                self._auth.operator_token(authorization[0])
                return
            if self._auth.logins.valid(cookie_value(req.headers, COOKIE)):
                if req.method != "GET" and (
                        "Origin" not in req.headers
                        or not origin_allowed(req.headers, self._tls, self._origins)):
                    raise AuthError(403, "a change by the GUI's login needs its own Origin")
                return
            raise AuthError(401, "missing token (Authorization: Bearer <operator token>)")
        except AuthError as exc:
            extra = [("WWW-Authenticate", "Bearer")] if exc.status == 401 else []
            raise HttpError(exc.status, exc.reason, extra) from None

    @staticmethod
    def _found(pool: TaskPool, task_id: int) -> Task:
        try:
            return pool.task(task_id)
        except TaskNotFound as exc:
            raise HttpError(404, str(exc)) from None

    # ------------------------------------------------------------------ changes
    async def _change(self, fn: Callable[[TaskPool, float], T]) -> T:
        """Run ``fn(pool, now)`` in the owner task; its result once the owner task committed
        the journal (it commits before it yields, and the result is seen only then)."""
        loop = asyncio.get_running_loop()
        done: asyncio.Future[T] = loop.create_future()
        engine = self._engine

        def call() -> None:
            pool = _pool(engine)
            try:
                if pool is None:
                    raise HttpError(503, "the task pool is gone")
                done.set_result(fn(pool, self.now_ms()))
            except Exception as exc:  # refusals, and bugs (logged by the HTTP layer)
                done.set_exception(exc)

        engine.queue.put_nowait(OwnerCall(call))
        try:
            return await done
        except TaskNotFound as exc:
            raise HttpError(404, str(exc)) from None
        except TaskConflict as exc:
            raise HttpError(409, str(exc)) from None
        except TaskError as exc:
            raise HttpError(422, str(exc)) from None

    async def _submit(self, req: ApiRequest, grid: Grid) -> ApiResponse:
        body = self._parse(req)
        keys = req.headers.get_all("Idempotency-Key")
        if len(keys) > 1:
            raise HttpError(400, "Idempotency-Key header given more than once")
        key = body.idempotency_key
        if keys:
            if key is not None and key != keys[0]:
                raise HttpError(400, "the Idempotency-Key header and the idempotency_key "
                                     "field differ")
            key = keys[0]
            try:
                body = type(body).model_validate({**body.model_dump(), "idempotency_key": key})
            except ValidationError as exc:
                raise HttpError(400, f"Idempotency-Key: {_first_error(exc)}") from None
        specs = body.tasks if isinstance(body, SubmitBatch) else [body]
        new = []
        for i, spec in enumerate(specs):
            for j, cell in enumerate(spec.errands):
                if not grid.is_free(cell):
                    where = f"tasks.{i}.errands.{j}" if isinstance(body, SubmitBatch) \
                        else f"errands.{j}"
                    raise HttpError(422, f"{where}: {list(cell)} is not a free cell of the map "
                                         f"({grid.width} x {grid.height})")
            new.append(NewTask(tuple(grid.index(c) for c in spec.errands), spec.priority,
                               spec.deadline_ms))

        def submit(pool: TaskPool, now: float) -> tuple[list[Task], bool]:
            ids, created = pool.submit(new, now, key)
            return [pool.task(i) for i in ids], created

        tasks, created = await self._change(submit)
        answer = SubmitResponse(created=created, tasks=[self._view(t, grid) for t in tasks])
        return json_answer(201 if created else 200, answer.model_dump(mode="json"))

    @staticmethod
    def _parse(req: ApiRequest) -> SubmitOne | SubmitBatch:
        ctype = req.headers.get("Content-Type", "")
        if ctype.split(";")[0].strip().lower() != "application/json":
            raise HttpError(415, "the body must be application/json")
        try:
            text = req.body.decode("utf-8")
        except UnicodeDecodeError:
            raise HttpError(400, "the body is not UTF-8") from None
        try:
            check_text(text)
        except ProtocolError as exc:
            raise HttpError(413 if exc.code.value == "too_large" else 400, exc.detail) from None
        try:
            data = json.loads(text)
        except json.JSONDecodeError as exc:
            raise HttpError(400, f"not JSON: {exc}") from None
        if not isinstance(data, dict):
            raise HttpError(400, "the body must be a JSON object: a task or {\"tasks\": [...]}")
        model: type[SubmitOne] | type[SubmitBatch] = SubmitBatch if "tasks" in data \
            else SubmitOne
        try:  # strict: "5", true and 1.0 are no integers, "100" is no number
            return model.model_validate_json(text, strict=True)
        except ValidationError as exc:
            raise HttpError(400, _first_error(exc)) from None

    # ------------------------------------------------------------------ reads
    def _list(self, req: ApiRequest, pool: TaskPool, grid: Grid) -> ApiResponse:
        query = self._query(req, {"state", "robot", "after", "limit"})
        states: frozenset[TaskState] | None = None
        if "state" in query:
            names = [s for v in query["state"] for s in v.split(",")]
            bad = [s for s in names if s not in TASK_STATES]
            if bad:
                raise HttpError(400, f"unknown state {bad[0]!r} (one of "
                                     f"{', '.join(TASK_STATES)})")
            states = frozenset(cast(list[TaskState], names))
        robot = self._int(query, "robot", 0, 1 << 30)
        after = self._int(query, "after", -1, 1 << 62)
        limit = self._int(query, "limit", 1, MAX_LIST)
        limit = MAX_LIST if limit is None else limit
        page: list[Task] = []
        more = False
        for task in pool.select(states, robot, -1 if after is None else after):
            if len(page) == limit:
                more = True
                break
            page.append(task)
        now = self.now_ms()
        answer = TaskList(now_ms=now, now_at=self.wall_time(now),
                          tasks=[self._view(t, grid) for t in page],
                          next_after=page[-1].id if more else None, counts=pool.counts(),
                          last_event=pool.event_seq)
        return json_answer(200, answer.model_dump(mode="json"))

    @staticmethod
    def _query(req: ApiRequest, allowed: set[str]) -> dict[str, list[str]]:
        if len(req.query) > 2000:
            raise HttpError(414, "the query is longer than 2000 characters")
        query = parse_qs(req.query, keep_blank_values=True)
        for name, values in query.items():
            if name not in allowed:
                raise HttpError(400, f"unknown query parameter {name[:40]!r} (known: "
                                     f"{', '.join(sorted(allowed))})")
            if len(values) > 1 and name != "state":
                raise HttpError(400, f"query parameter {name!r} given {len(values)} times")
        return query

    @staticmethod
    def _int(query: dict[str, list[str]], name: str, low: int, high: int) -> int | None:
        if name not in query:
            return None
        text = query[name][0]
        if not (text.lstrip("-").isdigit() and len(text) < 20) or not low <= int(text) <= high:
            raise HttpError(400, f"{name} must be an integer from {low} to {high}")
        return int(text)

    def _events(self, req: ApiRequest, pool: TaskPool) -> ApiResponse:
        query = self._query(req, {"after"})
        after = self._int(query, "after", 0, 1 << 62)
        last = req.headers.get_all("Last-Event-ID")
        if last:
            if len(last) > 1 or not last[0].isdigit() or len(last[0]) > 18:
                raise HttpError(400, "Last-Event-ID must be one event id (an integer)")
            after = int(last[0])
        if self.streams >= MAX_STREAMS:
            raise HttpError(503, f"{MAX_STREAMS} event streams are open", [("Retry-After", "5")])
        start = pool.event_seq if after is None else after
        return ApiResponse(200, content_type="text/event-stream",
                           stream=self._stream(start))

    async def _stream(self, after: int) -> AsyncIterator[bytes]:
        """Server-sent events after event ``after`` until the client goes."""
        self.streams += 1
        try:
            yield b"retry: 1000\n\n"
            idle = 0.0
            while True:
                pool = _pool(self._engine)
                if pool is None:
                    return
                if after > pool.event_seq:  # an id this gateway never gave (another shift's)
                    yield _reset(pool.event_seq + 1)
                    after = pool.event_seq
                events, complete = pool.events_after(after)
                if not complete:
                    yield _reset(events[0].seq if events else pool.event_seq + 1)
                if events:
                    idle = 0.0
                    chunk = "".join(
                        f"id: {e.seq}\nevent: task\ndata: "
                        f"{event_view(e, self.wall_time).model_dump_json()}\n\n"
                        for e in events)
                    after = events[-1].seq
                    yield chunk.encode()
                elif idle >= KEEPALIVE_S:
                    idle = 0.0
                    yield b": keepalive\n\n"
                await asyncio.sleep(POLL_S)
                idle += POLL_S
        finally:
            self.streams -= 1
