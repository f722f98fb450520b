"""The gateway's ASGI application (FastAPI): the task API (:mod:`gateway.server.task_api.api`),
the operator's plain routes (:mod:`gateway.server.wire.http`), the OpenAPI document FastAPI
generates from the routes and the pydantic models (``/openapi.json``, interactive at
``/docs``: ``fastapi-offline`` serves the Swagger UI files from the gateway itself, so a
warehouse network without internet access still gets working docs).

FastAPI rather than bare Starlette: it writes the OpenAPI document from the routes'
declared parameters, models and responses, which is the document integrators and
Schemathesis read; the routes are Starlette's underneath. Every response carries
``Cache-Control: no-store`` and the browser hardening headers; an exception a route did not
expect is a 500 ``{"error": "internal error"}`` and one log line, never a traceback.
"""

from __future__ import annotations

import logging
from functools import cache
from typing import Any

from fastapi import FastAPI, Request
from fastapi.openapi.utils import get_openapi
from fastapi.responses import JSONResponse
from fastapi_offline import FastAPIOffline
from pydantic.json_schema import models_json_schema
from starlette.types import ASGIApp, Message, Receive, Scope, Send

from gateway.execution.lifelong.tasks import TASK_STATES
from gateway.server.task_api import routes as task_routes
from gateway.server.task_api.models import (
    CLOCK,
    ResetEvent,
    SubmitBatch,
    SubmitOne,
    TaskEventView,
)
from gateway.server.wire import errors
from gateway.server.wire import http as plain_routes
from gateway.server.wire.auth import COOKIE

log = logging.getLogger("fleetgate.http")

SECURITY_HEADERS = [(b"cache-control", b"no-store"), (b"x-content-type-options", b"nosniff"),
                    (b"x-frame-options", b"DENY"), (b"referrer-policy", b"no-referrer")]
TITLE = "fleetgate task API"
DESCRIPTION = ("Tasks for a warehouse shift in lifelong mode. Cells are [x, y]. One clock: "
               f"{CLOCK}. States: " + ", ".join(TASK_STATES) + ".")
_REF = "#/components/schemas/{model}"


class Guard:
    """The outermost layer: the hardening headers on every response; an exception that
    escaped the application is logged as one line (a 500 was already sent, or is sent now)."""

    def __init__(self, app: ASGIApp) -> None:
        self.app = app

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        """Serve one request."""
        started = False

        async def guarded_send(message: Message) -> None:
            nonlocal started
            if message["type"] == "http.response.start":
                started = True
                message["headers"] = [*message.get("headers", ()), *SECURITY_HEADERS]
            await send(message)

        try:
            await self.app(scope, receive, guarded_send)
        except Exception as exc:
            log.error("request failed", extra={"path": str(scope.get("path", ""))[:200],
                                               "error": repr(exc)[:500]})
            if not started and scope["type"] == "http":
                await errors.refusal(500, "internal error")(scope, receive, guarded_send)


def _document(app: FastAPI) -> dict[str, Any]:
    """The OpenAPI document of ``app``'s routes, plus the models the routes read or stream
    themselves and the two ways to authenticate."""
    if app.openapi_schema is None:
        doc = get_openapi(title=TITLE, version="1", openapi_version="3.1.0",
                          description=DESCRIPTION, routes=app.routes)
        _, extra = models_json_schema(
            [(m, "validation") for m in (SubmitOne, SubmitBatch, TaskEventView, ResetEvent)],
            ref_template=_REF)
        schemas = doc.setdefault("components", {}).setdefault("schemas", {})
        for name, schema in extra.get("$defs", {}).items():
            schemas.setdefault(name, schema)
        doc["components"]["securitySchemes"] = {
            "bearer": {"type": "http", "scheme": "bearer", "description": "an operator token"},
            "login": {"type": "apiKey", "in": "cookie", "name": COOKIE,
                      "description": "the GUI's login (GET /session); changes need the "
                                     "gateway's own Origin"}}
        doc["security"] = [{"bearer": []}, {"login": []}]
        app.openapi_schema = doc
    return app.openapi_schema


def create_app() -> FastAPI:
    """The application; the gateway sets ``app.state.task_api`` (a
    :class:`~gateway.server.task_api.api.TaskApi`) and ``app.state.plain`` (a
    :class:`~gateway.server.wire.http.PlainRoutes`) before it serves."""
    app = FastAPIOffline(title=TITLE, version="1", description=DESCRIPTION, docs_url="/docs",
                         redoc_url=None, openapi_url="/openapi.json",
                         static_url="/docs/assets", default_response_class=errors.JsonAnswer)
    app.add_middleware(task_routes.TaskAuth)
    app.include_router(task_routes.router)
    app.include_router(plain_routes.router)
    errors.install(app)

    async def internal(_: Request, exc: Exception) -> JSONResponse:
        return errors.refusal(500, "internal error")

    app.add_exception_handler(Exception, internal)
    app.openapi = lambda: _document(app)  # type: ignore[method-assign]
    return app


@cache
def openapi_document() -> dict[str, Any]:
    """The task API's OpenAPI 3.1 document (what ``GET /openapi.json`` serves)."""
    return _document(create_app())
