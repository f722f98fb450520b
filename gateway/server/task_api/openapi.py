"""The OpenAPI 3.1 document of the task API (``GET /openapi.json``), generated from the pydantic
models of :mod:`gateway.server.task_api.models` and the route table below: nothing in it is
written by hand but the routes' words."""

from __future__ import annotations

from functools import cache
from typing import Any

from pydantic import BaseModel
from pydantic.json_schema import models_json_schema

from gateway.execution.lifelong.tasks import TASK_STATES
from gateway.server.task_api.models import (
    CLOCK,
    KEY_PATTERN,
    MAX_KEY_CHARS,
    MAX_LIST,
    ApiError,
    SubmitBatch,
    SubmitOne,
    SubmitResponse,
    TaskAction,
    TaskEventView,
    TaskList,
    TaskView,
)

MODELS: tuple[type[BaseModel], ...] = (SubmitOne, SubmitBatch, SubmitResponse, TaskView,
                                       TaskList, TaskEventView, TaskAction, ApiError)
_REF = "#/components/schemas/{model}"


def _ref(model: type[BaseModel]) -> dict[str, str]:
    return {"$ref": _REF.format(model=model.__name__)}


def _json(model: type[BaseModel], description: str) -> dict[str, Any]:
    return {"description": description, "content": {"application/json": {"schema": _ref(model)}}}


def _errors(*codes: int) -> dict[str, Any]:
    """The refusals an operation names, each and any other (``default``) an ApiError."""
    words = {400: "malformed request", 401: "no credentials", 403: "refused credentials",
             404: "no such task", 409: "conflict with the task's state, an idempotency key, or a "
                                     "shift that has ended",
             413: "body too large", 414: "query too long", 415: "body not JSON",
             422: "not a free cell of the map",
             503: "not in lifelong mode, or too many event streams"}
    return {**{str(c): _json(ApiError, words[c]) for c in codes},
            "default": _json(ApiError, "any other refusal (e.g. 408 request too slow, 417 "
                                       "unsupported Expect, 500 internal error)")}


_TASK_ID = {"name": "id", "in": "path", "required": True,
            "schema": {"type": "integer", "minimum": 0}}


def _paths() -> dict[str, Any]:
    auth = (400, 401, 403, 503)
    return {
        "/tasks": {
            "post": {
                "summary": "Submit one task or a batch",
                "operationId": "submitTasks",
                "parameters": [{"name": "Idempotency-Key", "in": "header", "required": False,
                                "schema": {"type": "string", "minLength": 1,
                                           "maxLength": MAX_KEY_CHARS,
                                           "pattern": KEY_PATTERN}}],
                "requestBody": {"required": True, "content": {"application/json": {
                    "schema": {"oneOf": [_ref(SubmitOne), _ref(SubmitBatch)]}}}},
                "responses": {
                    "201": _json(SubmitResponse, "the tasks were created"),
                    "200": _json(SubmitResponse, "a retry: the tasks of the first request"),
                    **_errors(*auth, 409, 413, 415, 422)},
            },
            "get": {
                "summary": "List tasks in id order, a page at a time",
                "operationId": "listTasks",
                "parameters": [
                    {"name": "state", "in": "query", "required": False,
                     "description": "comma-separated states",
                     "schema": {"type": "string"}, "examples": {
                         "open": {"value": "queued,assigned,started"}},
                     },
                    {"name": "robot", "in": "query", "required": False,
                     "schema": {"type": "integer", "minimum": 0}},
                    {"name": "after", "in": "query", "required": False,
                     "schema": {"type": "integer", "minimum": -1}},
                    {"name": "limit", "in": "query", "required": False,
                     "schema": {"type": "integer", "minimum": 1, "maximum": MAX_LIST}}],
                "responses": {"200": _json(TaskList, "a page of tasks"),
                              **_errors(*auth, 414)},
            },
        },
        "/tasks/{id}": {
            "get": {"summary": "One task", "operationId": "getTask", "parameters": [_TASK_ID],
                    "responses": {"200": _json(TaskView, "the task"),
                                  **_errors(*auth, 404)}},
            "delete": {"summary": "Cancel a task no errand of which is done",
                       "operationId": "cancelTask", "parameters": [_TASK_ID],
                       "responses": {"200": _json(TaskView, "the cancelled task"),
                                     **_errors(*auth, 404, 409)}},
        },
        "/tasks/{id}/pause": {
            "post": {"summary": "Hold a task not started yet (never assigned while paused)",
                     "operationId": "pauseTask", "parameters": [_TASK_ID],
                     "responses": {"200": _json(TaskAction, "the paused task"),
                                   **_errors(*auth, 404, 409)}},
        },
        "/tasks/{id}/resume": {
            "post": {"summary": "Queue a paused task again", "operationId": "resumeTask",
                     "parameters": [_TASK_ID],
                     "responses": {"200": _json(TaskAction, "the task"),
                                   **_errors(*auth, 404, 409)}},
        },
        "/tasks/events": {
            "get": {
                "summary": "Server-sent events: one per change of a task",
                "description": "Each event is `event: task`, `id: <seq>` and `data:` a "
                               "TaskEventView. Resume with the Last-Event-ID header (or "
                               "?after=seq); an `event: reset` says events were dropped "
                               "meanwhile, or the id is one this gateway never gave (another "
                               "shift's): read GET /tasks again.",
                "operationId": "taskEvents",
                "parameters": [
                    {"name": "Last-Event-ID", "in": "header", "required": False,
                     "schema": {"type": "integer", "minimum": 0}},
                    {"name": "after", "in": "query", "required": False,
                     "schema": {"type": "integer", "minimum": 0}}],
                "responses": {"200": {"description": "the stream", "content": {
                    "text/event-stream": {"schema": {"type": "string"},
                                          "x-event-data": _ref(TaskEventView)}}},
                    **_errors(*auth, 414)},
            },
        },
    }


@cache
def openapi_document() -> dict[str, Any]:
    """The task API's OpenAPI 3.1 document."""
    _, schemas = models_json_schema([(m, "validation") for m in MODELS], ref_template=_REF)
    return {
        "openapi": "3.1.0",
        "info": {"title": "fleetgate task API", "version": "1",
                 "description": "Tasks for a warehouse shift in lifelong mode. Cells are "
                                f"[x, y]. One clock: {CLOCK}. States: "
                                + ", ".join(TASK_STATES) + "."},
        "paths": _paths(),
        "components": {
            "schemas": schemas.get("$defs", {}),
            "securitySchemes": {
                "bearer": {"type": "http", "scheme": "bearer",
                           "description": "an operator token"},
                "login": {"type": "apiKey", "in": "cookie", "name": "fleetgate_session",
                          "description": "the GUI's login (GET /session); changes need the "
                                         "gateway's own Origin"}},
        },
        "security": [{"bearer": []}, {"login": []}],
    }


def _type(schema: dict[str, Any]) -> str:
    """A short name of a JSON schema's type."""
    if "$ref" in schema:
        return str(schema["$ref"]).rsplit("/", 1)[-1]
    if "anyOf" in schema:
        return " or ".join(_type(s) for s in schema["anyOf"])
    kind = schema.get("type", "any")
    if kind == "array":
        items = schema.get("items") or schema.get("prefixItems")
        if isinstance(items, list):
            return "[" + ", ".join(_type(s) for s in items) + "]"
        return f"list of {_type(items or {})}"
    if "enum" in schema:
        return " \\| ".join(f"`{v}`" for v in schema["enum"])
    if "const" in schema:
        return f"`{schema['const']}`"
    return str(kind)


def markdown() -> str:
    """``docs/tasks.md``: the task API, rendered from :func:`openapi_document` (a test keeps
    the file in step: ``python -m gateway.server.task_api.openapi > docs/tasks.md``)."""
    doc = openapi_document()
    out = ["# The task API", "",
           "Generated from the gateway's OpenAPI document (`GET /openapi.json`) by "
           "`python -m gateway.server.task_api.openapi`; do not edit.", "",
           doc["info"]["description"], "",
           "Credentials: `Authorization: Bearer <operator token>`, or the GUI's login "
           "cookie (changes also need the gateway's own `Origin`). Every refusal is a 4xx "
           "(or 503) with `{\"error\": \"<one line>\"}`. Changes are journaled and committed "
           "before they are answered.", "", "## Routes", ""]
    for path, ops in doc["paths"].items():
        for method, op in ops.items():
            out += [f"### `{method.upper()} {path}`", "", op["summary"] + ".", ""]
            if "description" in op:
                out += [op["description"], ""]
            for p in op.get("parameters", []):
                out.append(f"- {p['in']} `{p['name']}`: {_type(p['schema'])}"
                           + (f" ({p['description']})" if "description" in p else ""))
            out += [f"- {code}: {r['description']}" + "".join(
                f" (`{_type(c['schema'])}`)" for c in r.get("content", {}).values()
                if "$ref" in c.get("schema", {})) for code, r in op["responses"].items()]
            out.append("")
    out += ["## Models", ""]
    for name, schema in doc["components"]["schemas"].items():
        out += [f"### {name}", "", " ".join(schema.get("description", "").split()), "",
                "| field | type | required |", "| --- | --- | --- |"]
        required = set(schema.get("required", []))
        for field, prop in schema.get("properties", {}).items():
            out.append(f"| `{field}` | {_type(prop)} | {'yes' if field in required else ''} |")
        out.append("")
    return "\n".join(out)


if __name__ == "__main__":
    print(markdown(), end="")
