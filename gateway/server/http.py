"""Plain HTTP on the gateway's port: ``/metrics``, ``/healthz`` and the operator GUI's files."""

from __future__ import annotations

import mimetypes
from collections.abc import Callable
from pathlib import Path
from urllib.parse import unquote, urlsplit

from prometheus_client import CONTENT_TYPE_LATEST
from websockets.datastructures import Headers
from websockets.http11 import Response

import gateway.web

DEFAULT_STATIC = Path(gateway.web.__file__).resolve().parent / "static"
"""Where the GUI helper puts index.html and friends."""

TOKEN_PLACEHOLDER = b"{{OPERATOR_TOKEN}}"
"""In index.html, replaced by an operator token when the gateway is a loopback demo."""


def response(status: int, body: bytes, content_type: str = "text/plain; charset=utf-8",
             extra: list[tuple[str, str]] | None = None) -> Response:
    """A complete HTTP response."""
    reasons = {200: "OK", 404: "Not Found", 403: "Forbidden", 401: "Unauthorized",
               405: "Method Not Allowed", 426: "Upgrade Required"}
    headers = Headers([("Content-Type", content_type), ("Content-Length", str(len(body))),
                       ("Cache-Control", "no-store"), *(extra or [])])
    return Response(status, reasons.get(status, "Error"), headers, body)


class HttpRoutes:
    """Answers the non-websocket requests."""

    def __init__(self, metrics: Callable[[], bytes], health: Callable[[], bytes],
                 static_dir: Path | None = None, operator_token: str | None = None) -> None:
        self._metrics = metrics
        self._health = health
        self._root = (static_dir or DEFAULT_STATIC).resolve()
        self._token = operator_token

    def __call__(self, path: str) -> Response:
        """The response for a GET of ``path``."""
        route = urlsplit(path).path
        if route == "/metrics":
            return response(200, self._metrics(), CONTENT_TYPE_LATEST)
        if route == "/healthz":
            return response(200, self._health(), "application/json")
        return self._static(route)

    def _static(self, route: str) -> Response:
        rel = unquote(route).lstrip("/") or "index.html"
        target = (self._root / rel).resolve()
        if not target.is_relative_to(self._root) or not target.is_file():
            return response(404, b"not found\n")
        body = target.read_bytes()
        if target.name == "index.html" and self._token is not None:
            body = body.replace(TOKEN_PLACEHOLDER, self._token.encode())
        ctype = mimetypes.guess_type(target.name)[0] or "application/octet-stream"
        if ctype.startswith("text/") or ctype in ("application/javascript", "application/json"):
            ctype += "; charset=utf-8"
        return response(200, body, ctype)
