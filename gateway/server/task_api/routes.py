"""The task API's routes (a FastAPI router, :data:`router`) and its credentials middleware
(:class:`TaskAuth`); what they do is :class:`~gateway.server.task_api.api.TaskApi`'s. FastAPI
writes the OpenAPI document from these declarations: parameters with their types and limits,
the models of each answer, every refusal an :class:`~gateway.server.task_api.models.ApiError`.
"""

from __future__ import annotations

from collections.abc import Callable, Coroutine
from typing import Annotated, Any, Literal

from fastapi import APIRouter, Depends, Header, Path, Query, Request
from fastapi.responses import JSONResponse, Response, StreamingResponse
from fastapi.routing import APIRoute
from pydantic import BaseModel
from starlette.convertors import Convertor, register_url_convertor
from starlette.types import ASGIApp, Receive, Scope, Send

from gateway.server.task_api.api import KEY, KEY_HEADER, TaskApi, json_answer
from gateway.server.task_api.models import (
    MAX_LIST,
    ApiError,
    SubmitResponse,
    TaskAction,
    TaskList,
    TaskView,
)
from gateway.server.wire.errors import HttpError, refusal

MAX_QUERY_CHARS = 2000
"""Characters of a query string."""


class TaskIdConvertor(Convertor[str]):
    """A task id's place in a path: any segment but ``events`` (``/tasks/events`` is the
    stream's, whatever the method); FastAPI then checks it is a whole number (400)."""

    regex = "(?!events(?:/|$))[^/]+"

    def convert(self, value: str) -> str:
        """As written."""
        return value

    def to_string(self, value: str) -> str:
        """As written."""
        return value


register_url_convertor("task_id", TaskIdConvertor())


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


async def _api(request: Request) -> TaskApi:
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


def _ok(model: type[BaseModel], description: str, links: dict[str, Any] | None = None
        ) -> dict[str, Any]:
    return {"model": model, "description": description, **({"links": links} if links else {})}


FIRST_TASK = {op: {"operationId": op, "parameters": {"id": "$response.body#/tasks/0/id"},
                   "description": "the first task submitted"}
              for op in ("getTask", "cancelTask", "pauseTask", "resumeTask")}
"""The document's links from a submission to what can be done with its first task (what
Schemathesis' stateful phase follows)."""


router = APIRouter()
"""The task API's routes."""

SSE_EVENT = {
    "type": "object", "required": ["data"],
    "description": "one event of the stream (OpenAPI 3.1: the schema of each event)",
    "properties": {
        "event": {"enum": ["task", "reset"]},
        "id": {"type": "string", "pattern": "^[0-9]+$"},
        "retry": {"type": "integer"},
        "data": {"type": "string", "contentMediaType": "application/json",
                 "contentSchema": {"oneOf": [{"$ref": "#/components/schemas/TaskEventView"},
                                             {"$ref": "#/components/schemas/ResetEvent"}]}}}}
"""``GET /tasks/events``' events in the document: ``data`` is the JSON of a TaskEventView
(``event: task``, ``id`` its sequence number) or of a ResetEvent (``event: reset``)."""

KEY_PARAMETER = {"name": KEY_HEADER, "in": "header", "required": False,
                 "schema": {"anyOf": [KEY.json_schema(), {"type": "null"}],
                            "title": KEY_HEADER}}
"""``POST /tasks``' ``Idempotency-Key`` header in the document (the route reads it itself:
:func:`~gateway.server.task_api.api.TaskApi.submit`)."""

SUBMIT_BODY = {"required": True, "content": {"application/json": {"schema": {"oneOf": [
    {"$ref": "#/components/schemas/SubmitOne"}, {"$ref": "#/components/schemas/SubmitBatch"}]}}}}
"""``POST /tasks``' body in the document (the route reads it itself, strictly: see
:func:`_parse`); :mod:`gateway.server.task_api.openapi` adds the two models' schemas."""


class LeanRoute(APIRoute):
    """A route whose endpoint takes the request and answers it itself (FastAPI's documented
    way to customise a route's handling): its declaration still writes the document, but
    no dependency solving, parameter validation or answer serialisation runs per request
    (for ``POST /tasks`` they cost as much as the rest of a submission)."""

    def get_route_handler(self) -> Callable[[Request], Coroutine[Any, Any, Response]]:
        """The endpoint itself."""
        endpoint: Callable[[Request], Coroutine[Any, Any, Response]] = self.endpoint
        return endpoint


async def submit_tasks(request: Request) -> Response:
    """Submit one task or a batch, with an optional idempotency key."""
    return await (await _api(request)).submit(request)


router.add_api_route(
    "/tasks", submit_tasks, methods=["POST"], route_class_override=LeanRoute,
    operation_id="submitTasks", summary="Submit one task or a batch", status_code=201,
    response_model=None,
    responses={201: _ok(SubmitResponse, "the tasks were created", FIRST_TASK),
               200: _ok(SubmitResponse, "a retry: the tasks of the first request", FIRST_TASK),
               **_errors(408, 409, 413, 415, 422)},
    openapi_extra={"parameters": [KEY_PARAMETER], "requestBody": SUBMIT_BODY})


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
    return json_answer(200, api.page(request, robot, after, limit))


@router.get("/tasks/events", operation_id="taskEvents",
            summary="Server-sent events: one per change of a task",
            description="Each event is `event: task`, `id: <seq>` and `data:` a "
                        "TaskEventView. Resume with the Last-Event-ID header (or ?after=seq); "
                        "an `event: reset` says events were dropped meanwhile, or the id is "
                        "one this gateway never gave (another shift's): read GET /tasks "
                        "again. Anything the client sends on the stream is not read.",
            response_class=StreamingResponse,
            responses={200: {"description": "the stream", "content": {"text/event-stream": {
                "schema": SSE_EVENT}}}, **_errors(414)})
async def task_events(
        api: Api,
        last_event_id: Annotated[int | None, Header(alias="Last-Event-ID", ge=0, le=10**18)]
        = None,
        after: Annotated[int | None, Query(ge=0, le=1 << 62)] = None) -> StreamingResponse:
    """The event stream."""
    return api.events(after if last_event_id is None else last_event_id)


@router.get("/tasks/{id:task_id}", operation_id="getTask", summary="One task", response_model=None,
            responses={200: _ok(TaskView, "the task"), **_errors(404)})
async def get_task(api: Api, task_id: TaskId) -> JSONResponse:
    """One task."""
    return json_answer(200, api.view(api.found(task_id)))


@router.delete("/tasks/{id:task_id}", operation_id="cancelTask",
               summary="Cancel a task no errand of which is done", response_model=None,
               responses={200: _ok(TaskView, "the cancelled task"), **_errors(404, 409)})
async def cancel_task(api: Api, task_id: TaskId) -> JSONResponse:
    """Cancel a task."""
    api.pool()
    task = await api.change(lambda p, now: p.cancel(task_id, now))
    return json_answer(200, api.view(task))


async def _act(api: TaskApi, task_id: int, act: Literal["pause", "resume"]) -> JSONResponse:
    api.pool()
    if act == "resume":
        api.check_open()
    task = await api.change(lambda p, now: (p.pause if act == "pause" else p.resume)(
        task_id, now))
    return json_answer(200, TaskAction(action=act, task=api.view(task)))


@router.post("/tasks/{id:task_id}/pause", operation_id="pauseTask",
             summary="Hold a task not started yet (never assigned while paused)",
             response_model=None,
             responses={200: _ok(TaskAction, "the paused task"), **_errors(404, 409)})
async def pause_task(api: Api, task_id: TaskId) -> JSONResponse:
    """Pause a task."""
    return await _act(api, task_id, "pause")


@router.post("/tasks/{id:task_id}/resume", operation_id="resumeTask",
             summary="Queue a paused task again", response_model=None,
             responses={200: _ok(TaskAction, "the task"), **_errors(404, 409)})
async def resume_task(api: Api, task_id: TaskId) -> JSONResponse:
    """Resume a task."""
    return await _act(api, task_id, "resume")
