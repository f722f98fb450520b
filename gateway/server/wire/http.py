"""The operator's plain routes on the gateway's port (GET only; a route of :data:`router`):

* ``/`` and other static files: the GUI (no secrets in them: it logs in first);
* ``/login``: the login page; ``/session`` with ``Authorization: Bearer <operator token>``
  logs in (``204``, sets the :data:`~gateway.server.wire.auth.COOKIE` cookie: HttpOnly,
  SameSite=Strict, Secure under TLS); without it, ``200 {"role": "operator"}`` if the cookie
  is a live login, else ``401``; errors are ``{"error": "..."}`` with 400/401/403;
  ``/logout`` ends the login;
* ``/healthz`` (liveness: 200 while the engine runs, else 503), ``/readyz`` (readiness: 200
  once the gateway listens, else 503), ``/metrics`` (Prometheus);
* ``/ws`` without an upgrade: 426 (how a browser learns why its websocket failed; the upgrade
  itself never reaches the application: :mod:`gateway.server.wire.ws_endpoint`).

They find the gateway's side of them (:class:`PlainRoutes`) as ``app.state.plain``.
"""

from __future__ import annotations

import mimetypes
from collections.abc import Callable
from pathlib import Path

from fastapi import APIRouter, Request
from fastapi.responses import Response
from prometheus_client import CONTENT_TYPE_LATEST

import gateway.web
from gateway.server.wire.auth import COOKIE, Authenticator, AuthError, cookie_value, single_header
from gateway.server.wire.errors import HttpError, JsonAnswer, no_route

DEFAULT_STATIC = Path(gateway.web.__file__).resolve().parent / "static"
"""Where the GUI helper puts index.html and friends."""


class PlainRoutes:
    """The gateway's side of the plain routes: metrics, health, readiness, logins, files."""

    def __init__(self, metrics: Callable[[], bytes], health: Callable[[], tuple[bool, bytes]],
                 ready: Callable[[], bool], auth: Authenticator, *, tls: bool = False,
                 static_dir: Path | None = None) -> None:
        self.metrics = metrics
        self.health = health
        self.ready = ready
        self.auth = auth
        self._tls = tls
        self._root = (static_dir or DEFAULT_STATIC).resolve()

    def cookie(self, value: str, max_age: int) -> str:
        """The login cookie's ``Set-Cookie`` value."""
        secure = "; Secure" if self._tls else ""
        return (f"{COOKIE}={value}; Path=/; Max-Age={max_age}; HttpOnly; SameSite=Strict"
                f"{secure}")

    def session(self, request: Request) -> Response:
        """``GET /session`` (see the module doc)."""
        try:
            authorization = single_header(request.headers, "Authorization")
            if authorization is None:
                if self.auth.logins.valid(cookie_value(request.headers)):
                    return JsonAnswer({"role": "operator"})
                raise AuthError(401, "not logged in")
            self.auth.operator_token(authorization)
        except AuthError as exc:
            raise HttpError(exc.status, exc.reason) from None
        sid = self.auth.logins.create()
        max_age = int(self.auth.logins.ttl_s)
        return Response(status_code=204,
                        headers={"Set-Cookie": self.cookie(sid, max_age)})

    def static(self, route: str) -> Response:
        """A file of the GUI (404 outside the static directory)."""
        rel = route.lstrip("/") or "index.html"
        try:
            target = (self._root / rel).resolve()
            found = target.is_relative_to(self._root) and target.is_file()
            body = target.read_bytes() if found else b""
        except ValueError:  # NUL in the path
            found = False
        except OSError:  # out of file descriptors, unreadable
            return Response(b"try again later\n", 503, media_type="text/plain")
        if not found:
            raise HttpError(404, "not found")
        ctype = mimetypes.guess_type(target.name)[0] or "application/octet-stream"
        if ctype.startswith("text/") or ctype in ("application/javascript", "application/json"):
            ctype += "; charset=utf-8"
        return Response(body, 200, headers={"Content-Type": ctype})


def _plain(request: Request) -> PlainRoutes:
    plain: PlainRoutes = request.app.state.plain
    return plain


router = APIRouter(include_in_schema=False)
"""The plain routes."""


@router.get("/metrics")
async def metrics(request: Request) -> Response:
    """Prometheus metrics."""
    return Response(_plain(request).metrics(), 200, media_type=CONTENT_TYPE_LATEST)


@router.get("/healthz")
async def healthz(request: Request) -> Response:
    """Liveness."""
    alive, body = _plain(request).health()
    return Response(body, 200 if alive else 503, media_type="application/json")


@router.get("/readyz")
async def readyz(request: Request) -> Response:
    """Readiness."""
    ready = _plain(request).ready()
    return JsonAnswer({"ready": ready}, 200 if ready else 503)


@router.get("/session")
async def session(request: Request) -> Response:
    """Log in, or ask whether the cookie is a live login."""
    return _plain(request).session(request)


@router.get("/logout")
async def logout(request: Request) -> Response:
    """End the login."""
    plain = _plain(request)
    plain.auth.logins.end(cookie_value(request.headers))
    return Response(b"", 303, headers={"Location": "/login",
                                       "Set-Cookie": plain.cookie("", 0)})


@router.get("/ws")
async def ws_without_upgrade(request: Request) -> Response:
    """A plain GET of ``/ws``: its credentials are checked, then 426."""
    try:
        _plain(request).auth.handshake(request.headers, str(request.url), None)
    except AuthError as exc:
        extra = [("WWW-Authenticate", "Bearer")] if exc.status == 401 else []
        raise HttpError(exc.status, exc.reason, extra) from None
    return Response(b"websocket upgrade required\n", 426, media_type="text/plain",
                    headers={"Upgrade": "websocket"})


@router.get("/login")
async def login(request: Request) -> Response:
    """The login page."""
    return _plain(request).static("/login.html")


@router.get("/{path:path}")
async def static(request: Request, path: str) -> Response:
    """A file of the GUI."""
    if path == "tasks" or path.startswith("tasks/"):  # the task API's, not a file
        raise no_route(request)
    return _plain(request).static(path)
