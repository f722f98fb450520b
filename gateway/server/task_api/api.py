"""The task API for a warehouse system (WMS), on the gateway's port, authenticated like the
operator (``Authorization: Bearer <operator token>``, or the GUI's login cookie with a
same-origin ``Origin`` for changes).

Routes (:data:`router`, a FastAPI router; models: :mod:`gateway.server.task_api.models`; the
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
from typing import TYPE_CHECKING, Annotated, Any, Literal, Protocol, TypeVar, cast

from fastapi import APIRouter, Depends, Header, Path, Query, Request
from fastapi.responses import JSONResponse, StreamingResponse
from pydantic import BaseModel, ValidationError
from starlette.types import ASGIApp, Receive, Scope, Send

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
    KEY_PATTERN,
    MAX_BODY_BYTES,
    MAX_KEY_CHARS,
    MAX_LIST,
    ApiError,
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
from gateway.server.wire.errors import HttpError, JsonAnswer, first_error, refusal
from protocol.codec import ProtocolError, check_text

if TYPE_CHECKING:
    from gateway.planning.grid import Grid

KEEPALIVE_S = 15.0
"""A comment line on an idle event stream this often (proxies keep it open)."""
POLL_S = 0.1
"""How often an event stream looks for new events."""
MAX_STREAMS = 32
"""Event streams open at once."""
MAX_QUERY_CHARS = 2000
T = TypeVar("T")


def _reset(first: int) -> bytes:
    """The ``reset`` event: the stream goes on with event ``first``; re-read the tasks."""
    return f"event: reset\ndata: {json.dumps({'first': first})}\n\n".encode()


def _json(status: int, model: BaseModel) -> JSONResponse:
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
    """The task API's state and logic for one gateway (the routes of :data:`router` find it as
    ``app.state.task_api``; see the module doc)."""

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

    async def submit(self, request: Request, header_key: str | None) -> JSONResponse:
        """``POST /tasks``."""
        self.pool()
        self.check_open()
        body = _parse(request.headers.get("Content-Type", ""), await self.body(request))
        if len(request.headers.getlist("Idempotency-Key")) > 1:
            raise HttpError(400, "Idempotency-Key header given more than once")
        key = body.idempotency_key
        if header_key is not None:
            if key is not None and key != header_key:
                raise HttpError(400, "the Idempotency-Key header and the idempotency_key "
                                     "field differ")
            key = header_key
            body = type(body).model_validate({**body.model_dump(), "idempotency_key": key})
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
        return _json(201 if created else 200,
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


# ---------------------------------------------------------------------------- routes
def is_task_path(path: str) -> bool:
    """Whether ``path`` is the task API's (its credentials are checked before routing)."""
    return path == "/tasks" or path.startswith("/tasks/")


class TaskAuth:
    """ASGI middleware: a request for a task API path gets no further than its credentials
    (401/403 before routing, before its body is read; :meth:`TaskApi.authorize`)."""

    def __init__(self, app: ASGIApp) -> None:
        self.app = app

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        """Check, then pass the request on."""
        if scope["type"] == "http" and is_task_path(scope["path"]):
            try:
                scope["app"].state.task_api.authorize(Request(scope))
            except HttpError as exc:
                await refusal(exc.status, exc.message, exc.headers)(scope, receive, send)
                return
        await self.app(scope, receive, send)


def _api(request: Request) -> TaskApi:
    """The gateway's task API, once the request's query has only known, single
    parameters."""
    api: TaskApi = request.app.state.task_api
    route = request.scope.get("route")
    known = {p.alias for p in route.dependant.query_params} if route else set()
    query = request.url.query
    if len(query) > MAX_QUERY_CHARS:
        raise HttpError(414, f"the query is longer than {MAX_QUERY_CHARS} characters")
    for name in set(request.query_params):
        if name not in known:
            raise HttpError(400, f"unknown query parameter {name[:40]!r} (known: "
                                 f"{', '.join(sorted(known)) or 'none'})")
        if name != "state" and len(request.query_params.getlist(name)) > 1:
            raise HttpError(400, f"query parameter {name!r} given "
                                 f"{len(request.query_params.getlist(name))} times")
    return api


Api = Annotated[TaskApi, Depends(_api)]
TaskId = Annotated[int, Path(alias="id", ge=0, le=10**18)]
_WORDS = {400: "malformed request", 401: "no credentials", 403: "refused credentials",
          404: "no such task", 408: "the body did not arrive in time",
          409: "conflict with the task's state, an idempotency key, or a shift that has ended",
          413: "body too large", 414: "query too long", 415: "body not JSON",
          417: "unsupported Expect", 422: "not a free cell of the map",
          503: "not in lifelong mode, or too many event streams"}


def _errors(*codes: int) -> dict[int | str, dict[str, Any]]:
    """The refusals an operation names, each and any other (``default``) an ApiError."""
    auth = (400, 401, 403, 417, 503)
    return {**{c: {"model": ApiError, "description": _WORDS[c]}
               for c in sorted({*auth, *codes})},
            "default": {"model": ApiError, "description": "any other refusal (e.g. 405 "
                                                          "wrong method, 500 internal error)"}}


def _ok(model: type[BaseModel], description: str) -> dict[str, Any]:
    return {"model": model, "description": description}


router = APIRouter()
"""The task API's routes."""

SUBMIT_BODY = {"required": True, "content": {"application/json": {"schema": {"oneOf": [
    {"$ref": "#/components/schemas/SubmitOne"}, {"$ref": "#/components/schemas/SubmitBatch"}]}}}}
"""``POST /tasks``' body in the document (the route reads it itself, strictly: see
:func:`_parse`); :mod:`gateway.server.task_api.openapi` adds the two models' schemas."""


@router.post("/tasks", operation_id="submitTasks", summary="Submit one task or a batch",
             status_code=201, response_model=None,
             responses={201: _ok(SubmitResponse, "the tasks were created"),
                        200: _ok(SubmitResponse, "a retry: the tasks of the first request"),
                        **_errors(408, 409, 413, 415, 422)},
             openapi_extra={"requestBody": SUBMIT_BODY})
async def submit_tasks(
        request: Request, api: Api,
        key: Annotated[str | None, Header(alias="Idempotency-Key", min_length=1,
                                          max_length=MAX_KEY_CHARS, pattern=KEY_PATTERN)]
        = None) -> JSONResponse:
    """Submit one task or a batch, with an optional idempotency key."""
    return await api.submit(request, key)


@router.get("/tasks", operation_id="listTasks", summary="List tasks in id order, a page at "
            "a time", response_model=None,
            responses={200: _ok(TaskList, "a page of tasks"), **_errors(414)})
async def list_tasks(
        request: Request, api: Api,
        state: Annotated[str | None, Query(description="comma-separated states",
                                           examples=["queued,assigned,started"])] = None,
        robot: Annotated[int | None, Query(ge=0, le=1 << 30)] = None,
        after: Annotated[int | None, Query(ge=-1, le=1 << 62)] = None,
        limit: Annotated[int | None, Query(ge=1, le=MAX_LIST)] = None) -> JSONResponse:
    """A page of tasks."""
    del state  # read as a list by TaskApi.page
    return _json(200, api.page(request, robot, after, limit))


@router.get("/tasks/events", operation_id="taskEvents",
            summary="Server-sent events: one per change of a task",
            description="Each event is `event: task`, `id: <seq>` and `data:` a "
                        "TaskEventView. Resume with the Last-Event-ID header (or ?after=seq); "
                        "an `event: reset` says events were dropped meanwhile, or the id is "
                        "one this gateway never gave (another shift's): read GET /tasks "
                        "again. Anything the client sends on the stream is not read.",
            response_class=StreamingResponse,
            responses={200: {"description": "the stream", "content": {"text/event-stream": {
                "schema": {"type": "string"},
                "x-event-data": {"$ref": "#/components/schemas/TaskEventView"}}}},
                **_errors(414)})
async def task_events(
        api: Api,
        last_event_id: Annotated[int | None, Header(alias="Last-Event-ID", ge=0, le=10**18)]
        = None,
        after: Annotated[int | None, Query(ge=0, le=1 << 62)] = None) -> StreamingResponse:
    """The event stream."""
    return api.events(after if last_event_id is None else last_event_id)


@router.get("/tasks/{id}", operation_id="getTask", summary="One task", response_model=None,
            responses={200: _ok(TaskView, "the task"), **_errors(404)})
async def get_task(api: Api, task_id: TaskId) -> JSONResponse:
    """One task."""
    return _json(200, api.view(api.found(task_id)))


@router.delete("/tasks/{id}", operation_id="cancelTask",
               summary="Cancel a task no errand of which is done", response_model=None,
               responses={200: _ok(TaskView, "the cancelled task"), **_errors(404, 409)})
async def cancel_task(api: Api, task_id: TaskId) -> JSONResponse:
    """Cancel a task."""
    api.pool()
    task = await api.change(lambda p, now: p.cancel(task_id, now))
    return _json(200, api.view(task))


async def _act(api: TaskApi, task_id: int, act: Literal["pause", "resume"]) -> JSONResponse:
    api.pool()
    if act == "resume":
        api.check_open()
    task = await api.change(lambda p, now: (p.pause if act == "pause" else p.resume)(
        task_id, now))
    return _json(200, TaskAction(action=act, task=api.view(task)))


@router.post("/tasks/{id}/pause", operation_id="pauseTask",
             summary="Hold a task not started yet (never assigned while paused)",
             response_model=None,
             responses={200: _ok(TaskAction, "the paused task"), **_errors(404, 409)})
async def pause_task(api: Api, task_id: TaskId) -> JSONResponse:
    """Pause a task."""
    return await _act(api, task_id, "pause")


@router.post("/tasks/{id}/resume", operation_id="resumeTask",
             summary="Queue a paused task again", response_model=None,
             responses={200: _ok(TaskAction, "the task"), **_errors(404, 409)})
async def resume_task(api: Api, task_id: TaskId) -> JSONResponse:
    """Resume a task."""
    return await _act(api, task_id, "resume")
