"""The task API for a warehouse system (WMS), on the gateway's port, authenticated like the
operator (``Authorization: Bearer <operator token>``, or the GUI's login cookie with a
same-origin ``Origin`` for changes).

Routes (:mod:`gateway.server.task_api.routes`; models: :mod:`gateway.server.task_api.models`; the
OpenAPI document FastAPI generates from them: ``GET /openapi.json``, interactive at ``/docs``):

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
only committed state. Refusals are 4xx with ``{"error": "<one line>"}``. Credentials are
checked before a body is read; a body is read within ``body_timeout_s`` (408) and at most
``MAX_BODY_BYTES`` (413).
"""

from __future__ import annotations

import asyncio
import json
from collections.abc import AsyncIterator, Callable
from typing import TYPE_CHECKING, Protocol, TypeVar, cast

from fastapi import Request
from fastapi.responses import JSONResponse, StreamingResponse
from pydantic import BaseModel, TypeAdapter, ValidationError

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
    MAX_BODY_BYTES,
    MAX_LIST,
    Key,
    ResetEvent,
    SubmitBatch,
    SubmitOne,
    SubmitResponse,
    TaskList,
    TaskView,
    event_view,
    iso_utc,
    task_view,
)
from gateway.server.wire.auth import COOKIE, Authenticator, AuthError, cookie_value, origin_allowed
from gateway.server.wire.errors import HttpError, JsonAnswer, first_error
from protocol.codec import ProtocolError, check_text

if TYPE_CHECKING:
    from gateway.planning.grid import Grid

KEEPALIVE_S = 15.0
"""A comment line on an idle event stream this often (proxies keep it open)."""
POLL_S = 0.1
"""How often an event stream looks for new events."""
MAX_STREAMS = 32
"""Event streams open at once."""
KEY_HEADER = "Idempotency-Key"
KEY: TypeAdapter[str] = TypeAdapter(Key)
"""What an idempotency key is (the header's and the body field's)."""
T = TypeVar("T")


def _reset(first: int) -> bytes:
    """The ``reset`` event: the stream goes on with event ``first``; re-read the tasks."""
    return f"event: reset\ndata: {ResetEvent(first=first).model_dump_json()}\n\n".encode()


def json_answer(status: int, model: BaseModel) -> JSONResponse:
    """A model as the JSON answer."""
    return JsonAnswer(model.model_dump(mode="json"), status)


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
    """The task API's state and logic for one gateway (the routes of
    :mod:`gateway.server.task_api.routes` find it as ``app.state.task_api``; see the module
    doc)."""

    def __init__(self, owner: Owner, auth: Authenticator, *, tls: bool,
                 allowed_origins: list[str], body_timeout_s: float = 10.0) -> None:
        self._engine = owner
        self._auth = auth
        self._tls = tls
        self._origins = allowed_origins
        self.body_timeout_s = body_timeout_s
        self.streams = 0
        """Event streams open now."""
        self.closing = False
        """Set when the gateway stops: event streams end."""

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

    def view(self, task: Task) -> TaskView:
        """What the API shows of a task."""
        return task_view(task, self.grid(), self.wall_time)

    def grid(self) -> Grid:
        """The shift's map."""
        run = self._engine.lifelong
        assert run is not None
        return run.shift.grid

    def pool(self) -> TaskPool:
        """The shift's task pool; HttpError(503) if the gateway runs no shift."""
        pool = _pool(self._engine)
        if pool is None:
            raise HttpError(503, "no task pool: the gateway is not in lifelong mode")
        return pool

    def check_open(self) -> None:
        """HttpError(409) if the shift is stopping or over (robots take no new task)."""
        run = self._engine.lifelong
        assert run is not None
        if run.executor.mode in (LifelongMode.STOPPING, LifelongMode.DONE):
            raise HttpError(409, "the shift has ended: no new task would run")

    def authorize(self, request: Request) -> None:
        """An operator's token, or the GUI's login (same origin for changes); HttpError.
        Called before anything of the body is read."""
        headers = request.headers
        try:
            authorization = headers.getlist("Authorization")
            if len(authorization) > 1:
                raise AuthError(400, "Authorization header given more than once")
            if authorization:
                self._auth.operator_token(authorization[0])
            elif self._auth.logins.valid(cookie_value(headers, COOKIE)):
                if request.method != "GET" and (
                        "Origin" not in headers
                        or not origin_allowed(headers, self._tls, self._origins)):
                    raise AuthError(403, "a change by the GUI's login needs its own Origin")
            else:
                raise AuthError(401, "missing token (Authorization: Bearer <operator token>)")
        except AuthError as exc:
            extra = [("WWW-Authenticate", "Bearer")] if exc.status == 401 else []
            raise HttpError(exc.status, exc.reason, extra) from None
        expect = [e.lower() for e in headers.getlist("Expect")]
        if expect and expect != ["100-continue"]:
            raise HttpError(417, f"unsupported Expect: {', '.join(expect)[:60]} (only "
                                 "100-continue)")

    async def change(self, fn: Callable[[TaskPool, float], T]) -> T:
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
            except Exception as exc:  # refusals, and bugs (answered 500 by the app)
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

    async def body(self, request: Request) -> bytes:
        """The request's body: at most MAX_BODY_BYTES (413), within ``body_timeout_s``
        (408)."""
        length = request.headers.get("Content-Length")
        if length is not None and length.isdigit() and int(length) > MAX_BODY_BYTES:
            raise HttpError(413, f"the body has {length} bytes, more than {MAX_BODY_BYTES}")
        data = bytearray()
        try:
            async with asyncio.timeout(self.body_timeout_s):
                async for chunk in request.stream():
                    data += chunk
                    if len(data) > MAX_BODY_BYTES:
                        raise HttpError(413, f"the body has more than {MAX_BODY_BYTES} bytes")
        except TimeoutError:
            raise HttpError(408, f"no complete body within {self.body_timeout_s} s") from None
        return bytes(data)

    async def submit(self, request: Request) -> JSONResponse:
        """``POST /tasks``."""
        header_key = _header_key(request)
        self.pool()
        self.check_open()
        body = _parse(request.headers.get("Content-Type", ""), await self.body(request))
        key = body.idempotency_key
        if header_key is not None:
            if key is not None and key != header_key:
                raise HttpError(400, "the Idempotency-Key header and the idempotency_key "
                                     "field differ")
            key = header_key
        grid = self.grid()
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

        tasks, created = await self.change(submit)
        return json_answer(201 if created else 200,
                     SubmitResponse(created=created, tasks=[self.view(t) for t in tasks]))

    def found(self, task_id: int) -> Task:
        """The task; HttpError(404) if there is none."""
        try:
            return self.pool().task(task_id)
        except TaskNotFound as exc:
            raise HttpError(404, str(exc)) from None

    def page(self, request: Request, robot: int | None, after: int | None,
             limit: int | None) -> TaskList:
        """``GET /tasks``."""
        pool = self.pool()
        states: frozenset[TaskState] | None = None
        given = request.query_params.getlist("state")
        if given:
            names = [s for v in given for s in v.split(",")]
            bad = [s for s in names if s not in TASK_STATES]
            if bad:
                raise HttpError(400, f"unknown state {bad[0]!r} (one of "
                                     f"{', '.join(TASK_STATES)})")
            states = frozenset(cast(list[TaskState], names))
        limit = MAX_LIST if limit is None else limit
        page: list[Task] = []
        more = False
        for task in pool.select(states, robot, -1 if after is None else after):
            if len(page) == limit:
                more = True
                break
            page.append(task)
        now = self.now_ms()
        return TaskList(now_ms=now, now_at=self.wall_time(now),
                        tasks=[self.view(t) for t in page],
                        next_after=page[-1].id if more else None, counts=pool.counts(),
                        last_event=pool.event_seq)

    def events(self, after: int | None) -> StreamingResponse:
        """``GET /tasks/events``."""
        pool = self.pool()
        if self.streams >= MAX_STREAMS:
            raise HttpError(503, f"{MAX_STREAMS} event streams are open", [("Retry-After", "5")])
        start = pool.event_seq if after is None else after
        return StreamingResponse(self._stream(start),
                                 headers={"Content-Type": "text/event-stream"})

    async def _stream(self, after: int) -> AsyncIterator[bytes]:
        """Server-sent events after event ``after`` until the client goes (the server then
        cancels this) or the gateway stops."""
        self.streams += 1
        try:
            yield b"retry: 1000\n\n"
            idle = 0.0
            while not self.closing:
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


def _header_key(request: Request) -> str | None:
    """The ``Idempotency-Key`` header (None if absent), checked as the body's field is
    (:data:`~gateway.server.task_api.models.Key`); HttpError(400). Read here rather than
    declared as a FastAPI parameter: the framework's parameter machinery cost as much as
    the rest of a submission (the document declares it: ``routes.KEY_PARAMETER``)."""
    values = request.headers.getlist(KEY_HEADER)
    if len(values) > 1:
        raise HttpError(400, f"{KEY_HEADER} header given more than once")
    if not values:
        return None
    try:
        return KEY.validate_python(values[0])
    except ValidationError as exc:
        raise HttpError(400, first_error([{**e, "loc": ("header", KEY_HEADER)}
                                          for e in exc.errors(include_url=False)])) from None


def _parse(content_type: str, raw: bytes) -> SubmitOne | SubmitBatch:
    """A submission's body, strictly ("5", true and 1.0 are no integers); HttpError."""
    if content_type.split(";")[0].strip().lower() != "application/json":
        raise HttpError(415, "the body must be application/json")
    try:
        text = raw.decode("utf-8")
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
    model: type[SubmitOne] | type[SubmitBatch] = SubmitBatch if "tasks" in data else SubmitOne
    try:
        return model.model_validate_json(text, strict=True)
    except ValidationError as exc:
        raise HttpError(400, first_error(exc.errors(include_url=False))) from None


