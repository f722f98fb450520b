"""Plain HTTP(S) on the gateway's port: the operator GUI's files, its login, probes, metrics.

Routes (GET only; everything else is a websocket upgrade to ``/ws``):

* ``/`` and other static files: the GUI (no secrets in them: it logs in first);
* ``/login``: the login page; ``/session`` with ``Authorization: Bearer <operator token>``
  logs in (``204``, sets the :data:`~gateway.server.wire.auth.COOKIE` cookie: HttpOnly,
  SameSite=Strict, Secure under TLS); without it, ``200 {"role": "operator"}`` if the cookie
  is a live login, else ``401``; errors are ``{"error": "..."}`` with 400/401/403;
  ``/logout`` ends the login;
* ``/openapi.json``: the task API's OpenAPI document (:mod:`gateway.server.task_api.api`
  serves the API itself: :mod:`gateway.server.wire.http_api` takes its requests off the websocket
  server);
* ``/healthz`` (liveness: 200 while the engine runs, else 503), ``/readyz`` (readiness: 200
  once the gateway listens, else 503), ``/metrics`` (Prometheus).
"""

from __future__ import annotations

import json
import mimetypes
from collections.abc import Callable
from pathlib import Path
from urllib.parse import unquote, urlsplit

from prometheus_client import CONTENT_TYPE_LATEST
from websockets.datastructures import Headers
from websockets.http11 import Request, Response

import gateway.web
from gateway.server.task_api.openapi import openapi_document
from gateway.server.wire.auth import COOKIE, Authenticator, AuthError, cookie_value, single_header

DEFAULT_STATIC = Path(gateway.web.__file__).resolve().parent / "static"
"""Where the GUI helper puts index.html and friends."""

REASONS = {200: "OK", 201: "Created", 204: "No Content", 303: "See Other", 400: "Bad Request",
           401: "Unauthorized", 403: "Forbidden", 404: "Not Found", 405: "Method Not Allowed",
           408: "Request Timeout", 409: "Conflict", 413: "Content Too Large",
           414: "URI Too Long", 415: "Unsupported Media Type", 417: "Expectation Failed",
           422: "Unprocessable Content",
           426: "Upgrade Required", 500: "Internal Server Error", 501: "Not Implemented",
           503: "Service Unavailable"}

SECURITY_HEADERS = [("X-Content-Type-Options", "nosniff"), ("X-Frame-Options", "DENY"),
                    ("Referrer-Policy", "no-referrer")]


def response(status: int, body: bytes, content_type: str = "text/plain; charset=utf-8",
             extra: list[tuple[str, str]] | None = None) -> Response:
    """A complete HTTP response."""
    headers = Headers([("Content-Type", content_type), ("Content-Length", str(len(body))),
                       ("Cache-Control", "no-store"), *SECURITY_HEADERS, *(extra or [])])
    return Response(status, REASONS.get(status, "Error"), headers, body)


def json_response(status: int, data: object, extra: list[tuple[str, str]] | None = None
                  ) -> Response:
    """A JSON response."""
    return response(status, json.dumps(data).encode(), "application/json", extra)


class HttpRoutes:
    """Answers the non-websocket requests (see the module doc)."""

    def __init__(self, metrics: Callable[[], bytes], health: Callable[[], tuple[bool, bytes]],
                 ready: Callable[[], bool], auth: Authenticator, *, tls: bool = False,
                 static_dir: Path | None = None) -> None:
        self._metrics = metrics
        self._health = health
        self._ready = ready
        self._auth = auth
        self._tls = tls
        self._root = (static_dir or DEFAULT_STATIC).resolve()

    def __call__(self, request: Request) -> Response:
        """The response for a GET request."""
        route = urlsplit(request.path).path
        if route == "/metrics":
            return response(200, self._metrics(), CONTENT_TYPE_LATEST)
        if route == "/healthz":
            alive, body = self._health()
            return response(200 if alive else 503, body, "application/json")
        if route == "/readyz":
            ready = self._ready()
            return json_response(200 if ready else 503, {"ready": ready})
        if route == "/openapi.json":
            return json_response(200, openapi_document())
        if route == "/session":
            return self._session(request.headers)
        if route == "/logout":
            self._auth.logins.end(cookie_value(request.headers))
            return response(303, b"", extra=[("Location", "/login"),
                                             ("Set-Cookie", self._cookie("", 0))])
        if route == "/login":
            route = "/login.html"
        return self.static(route)

    def _cookie(self, value: str, max_age: int) -> str:
        secure = "; Secure" if self._tls else ""
        return (f"{COOKIE}={value}; Path=/; Max-Age={max_age}; HttpOnly; SameSite=Strict"
                f"{secure}")

    def _session(self, headers: Headers) -> Response:
        try:
            authorization = single_header(headers, "Authorization")
            if authorization is None:
                if self._auth.logins.valid(cookie_value(headers)):
                    return json_response(200, {"role": "operator"})
                raise AuthError(401, "not logged in")
            self._auth.operator_token(authorization)
        except AuthError as exc:
            return json_response(exc.status, {"error": exc.reason})
        sid = self._auth.logins.create()
        max_age = int(self._auth.logins.ttl_s)
        return response(204, b"", extra=[("Set-Cookie", self._cookie(sid, max_age))])

    def static(self, route: str) -> Response:
        """A file of the GUI (404 outside the static directory)."""
        rel = unquote(route).lstrip("/") or "index.html"
        try:
            target = (self._root / rel).resolve()
            found = target.is_relative_to(self._root) and target.is_file()
            body = target.read_bytes() if found else b""
        except ValueError:  # NUL in the path
            found = False
        except OSError:  # out of file descriptors, unreadable
            return response(503, b"try again later\n")
        if not found:
            return response(404, b"not found\n")
        ctype = mimetypes.guess_type(target.name)[0] or "application/octet-stream"
        if ctype.startswith("text/") or ctype in ("application/javascript", "application/json"):
            ctype += "; charset=utf-8"
        return response(200, body, ctype)
