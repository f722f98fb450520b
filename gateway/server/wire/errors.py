"""Refusals on the HTTP surface: every one is ``{"error": "<one line>"}`` with its status, the
framework's own (no route, wrong method, a parameter that fails its declared type) included.

:class:`HttpError` is what a route raises; :func:`install` makes the application answer it,
Starlette's ``HTTPException`` (404, 405 with ``Allow``) and FastAPI's validation errors (400:
the first failing parameter and why) that way. A refusal closes the connection
(``Connection: close``): a body the route did not read is not read at all.
"""

from __future__ import annotations

import json
from collections.abc import Iterator, Sequence
from typing import Any

from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from starlette.exceptions import HTTPException
from starlette.routing import Route


class HttpError(Exception):
    """A request is refused with ``status`` and a one-line message."""

    def __init__(self, status: int, message: str,
                 headers: list[tuple[str, str]] | None = None) -> None:
        super().__init__(message)
        self.status = status
        self.message = message
        self.headers = headers or []


class JsonAnswer(JSONResponse):
    """A JSON response as ``json.dumps`` writes it (ASCII, ``", "`` and ``": "``)."""

    def render(self, content: Any) -> bytes:
        """The body."""
        return json.dumps(content).encode()


def refusal(status: int, message: str, headers: list[tuple[str, str]] | None = None
            ) -> JSONResponse:
    """The JSON answer of a refusal (the connection is closed after it)."""
    return JsonAnswer({"error": message}, status,
                      headers={**dict(headers or []), "Connection": "close"})


def first_error(errors: Sequence[Any]) -> str:
    """``where: why`` of the first of pydantic's or FastAPI's validation errors."""
    err = errors[0]
    loc = [str(p) for p in err.get("loc", ()) or ()]
    where = ".".join(p for p in loc[1 if loc and loc[0] in ("query", "header", "path",
                                                                     "cookie") else 0:]
                     if not p.startswith("function-"))
    msg = " ".join(str(err.get("msg", "invalid")).split())
    return f"{where}: {msg}" if where else msg


def _routes(routes: Sequence[Any]) -> Iterator[Route]:
    """Every route, those of included routers too."""
    for route in routes:
        if isinstance(route, Route):
            yield route
        elif (included := getattr(route, "original_router", None)) is not None:
            yield from _routes(included.routes)


def _allowed(request: Request) -> list[str]:
    """The methods the most specific routes matching the request's path take (fewest
    parameters: ``/tasks/events`` over ``/tasks/{id}``; the GUI's catch-all of static files
    only if no other route matches)."""
    found: dict[str, tuple[int, set[str]]] = {}
    for route in _routes(request.app.router.routes):
        if route.path_regex.match(request.url.path):
            params = 0 if route.path == "/{path:path}" else len(route.param_convertors)
            found.setdefault(route.path, (params, set()))[1].update(route.methods or ())
    if len(found) > 1:
        found.pop("/{path:path}", None)
    fewest = min((p for p, _ in found.values()), default=0)
    methods = {m for p, ms in found.values() if p == fewest for m in ms} - {"HEAD"}
    order = ["GET", "POST", "PUT", "PATCH", "DELETE"]
    return sorted(methods, key=lambda m: order.index(m) if m in order else len(order))


def _method_message(request: Request, methods: list[str]) -> str:
    path = request.url.path[:100]
    if methods == ["GET"]:
        return f"{request.method} {path}: only GET is served here"
    return f"{request.method} {path}: use {' or '.join(methods)}"


def no_route(request: Request) -> HttpError:
    """The refusal of a request no route takes: 405 if a route has its path, else 404."""
    methods = _allowed(request)
    if methods and methods != ["GET"]:
        return HttpError(405, _method_message(request, methods), [("Allow", ", ".join(methods))])
    return HttpError(404, f"no route {request.url.path[:100]}")


def install(app: FastAPI) -> None:
    """Answer every refusal of ``app`` as the module doc says."""

    async def http_error(_: Request, exc: Exception) -> JSONResponse:
        assert isinstance(exc, HttpError)
        return refusal(exc.status, exc.message, exc.headers)

    async def framework(request: Request, exc: Exception) -> JSONResponse:
        assert isinstance(exc, HTTPException)
        headers = dict(exc.headers or {})
        if exc.status_code in (404, 405):
            error = no_route(request) if exc.status_code == 404 or _allowed(request) != ["GET"] \
                else HttpError(405, _method_message(request, ["GET"]), [("Allow", "GET")])
            return refusal(error.status, error.message, error.headers)
        return refusal(exc.status_code, str(exc.detail), list(headers.items()))

    async def invalid(_: Request, exc: Exception) -> JSONResponse:
        assert isinstance(exc, RequestValidationError)
        return refusal(400, first_error(list(exc.errors())))

    app.add_exception_handler(HttpError, http_error)
    app.add_exception_handler(HTTPException, framework)
    app.add_exception_handler(RequestValidationError, invalid)
