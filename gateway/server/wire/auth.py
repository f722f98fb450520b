"""Who is on the other end of a connection, decided once at the websocket handshake.

Credentials, in this order: a bearer token (``Authorization: Bearer <t>`` or ``?token=<t>``),
the GUI's login cookie (:data:`COOKIE`, set by ``GET /session`` with an operator token) or a
verified TLS client certificate issued to ``fleetgate:robot:<id>``. Refusals are
:class:`AuthError` with status 400 (malformed request), 401 (no credentials) or 403 (refused).
"""

from __future__ import annotations

import secrets
import time
from collections import OrderedDict
from dataclasses import dataclass
from typing import Any, Literal
from urllib.parse import parse_qs, urlsplit

from starlette.datastructures import Headers as RequestHeaders
from websockets.datastructures import Headers as WsHeaders

from gateway.server.config import TokensConfig
from protocol.tls import ROBOT_IDENTITY

Role = Literal["robot", "operator", "world"]
Headers = WsHeaders | RequestHeaders
"""A request's headers: of a websocket handshake, or of an HTTP request."""

COOKIE = "fleetgate_session"
"""Name of the GUI's login cookie (HttpOnly, SameSite=Strict, Secure under TLS)."""

MAX_TOKEN_CHARS = 512


@dataclass(frozen=True)
class Peer:
    """An authenticated connection: its role and, for a robot, the robot id bound to its token."""

    role: Role
    robot_id: int | None = None

    def __str__(self) -> str:
        return f"robot {self.robot_id}" if self.role == "robot" else self.role


class AuthError(Exception):
    """The handshake is refused with HTTP ``status`` (400, 401 or 403) for ``reason``."""

    def __init__(self, status: int, reason: str) -> None:
        super().__init__(reason)
        self.status = status
        self.reason = reason


def _robot_id(text: str) -> int | None:
    """``<id>`` of ``fleetgate:robot:<id>`` (ASCII digits, at most 8), else None."""
    if not text.startswith(ROBOT_IDENTITY):
        return None
    rest = text[len(ROBOT_IDENTITY):]
    return int(rest) if rest.isascii() and rest.isdigit() and len(rest) < 9 else None


def cert_robot_id(cert: dict[str, Any] | None) -> int | None:
    """The robot a verified client certificate (``SSLSocket.getpeercert()``) is issued to:
    a SAN URI, else the common name, ``fleetgate:robot:<id>``. None if it names no robot;
    AuthError(403) if it names two different robots."""
    if not cert:
        return None
    names = [v for k, v in cert.get("subjectAltName", ()) if k == "URI"]
    if not names:
        names = [v for rdn in cert.get("subject", ()) for k, v in rdn if k == "commonName"]
    ids = {i for i in map(_robot_id, names) if i is not None}
    if len(ids) > 1:
        raise AuthError(403, "the client certificate names more than one robot")
    return ids.pop() if ids else None


def _check_token(token: str) -> str:
    if not (token.isascii() and token.isprintable()) or len(token) > MAX_TOKEN_CHARS:
        raise AuthError(400, f"a token is printable ASCII, at most {MAX_TOKEN_CHARS} chars")
    return token


def header_values(headers: Headers, name: str) -> list[str]:
    """Every value of header ``name``, in order."""
    return headers.get_all(name) if isinstance(headers, WsHeaders) else headers.getlist(name)


def single_header(headers: Headers, name: str) -> str | None:
    """The value of a header that may appear at most once; AuthError(400) if repeated."""
    values = header_values(headers, name)
    if len(values) > 1:
        raise AuthError(400, f"{name} header given {len(values)} times")
    return values[0] if values else None


def request_token(authorization: str | None, path: str) -> str | None:
    """The token of a handshake: ``Authorization: Bearer <t>`` header, else ``?token=<t>``."""
    if authorization:
        scheme, _, value = authorization.partition(" ")
        if scheme.lower() == "bearer" and value.strip():
            return value.strip()
    values = parse_qs(urlsplit(path).query).get("token")
    if values and len(values) > 1:
        raise AuthError(400, "token given more than once in the query")
    return values[0] if values else None


def cookie_value(headers: Headers, name: str = COOKIE) -> str | None:
    """The value of cookie ``name`` in the request (None if absent or repeated)."""
    found = [v.strip() for header in header_values(headers, "Cookie") for part in header.split(";")
             for k, _, v in [part.partition("=")] if k.strip() == name]
    return found[0] if len(found) == 1 else None


class Logins:
    """GUI login sessions: random ids (the cookie's value) valid for ``ttl_s`` seconds."""

    MAX = 1024
    """At most this many live logins; the oldest is forgotten first."""

    def __init__(self, ttl_s: float) -> None:
        self.ttl_s = ttl_s
        self._expiry: OrderedDict[str, float] = OrderedDict()

    def create(self) -> str:
        """A new login's session id."""
        sid = secrets.token_urlsafe(32)
        self._expiry[sid] = time.monotonic() + self.ttl_s
        while len(self._expiry) > self.MAX:
            self._expiry.popitem(last=False)
        return sid

    def valid(self, sid: str | None) -> bool:
        """True if ``sid`` is a live login."""
        if sid is None:
            return False
        expiry = self._expiry.get(sid)
        if expiry is None:
            return False
        if expiry < time.monotonic():
            del self._expiry[sid]
            return False
        return True

    def end(self, sid: str | None) -> None:
        """Forget a login (logout)."""
        if sid is not None:
            self._expiry.pop(sid, None)


class Authenticator:
    """Maps credentials to peers according to the configured tokens (and client CA)."""

    def __init__(self, tokens: TokensConfig, *, robots_need_cert: bool = False,
                 login_ttl_s: float = 12 * 3600.0) -> None:
        self._robots = dict(tokens.robots)
        self._operators = frozenset(tokens.operators)
        self._world = frozenset(tokens.world)
        self._prefix = tokens.demo_robot_prefix
        self._robots_need_cert = robots_need_cert
        self.logins = Logins(login_ttl_s)

    def identify(self, token: str | None) -> Peer:
        """The peer a token stands for; AuthError if it is missing, malformed or unknown."""
        if not token:
            raise AuthError(401, "missing token (Authorization: Bearer <token> or ?token=)")
        _check_token(token)
        if token in self._robots:
            return Peer("robot", self._robots[token])
        if token in self._operators:
            return Peer("operator")
        if token in self._world:
            return Peer("world")
        if self._prefix and token.startswith(self._prefix):
            rest = token[len(self._prefix):]
            if rest.isascii() and rest.isdigit() and len(rest) < 9:
                return Peer("robot", int(rest))
        raise AuthError(403, "unknown token")

    def handshake(self, headers: Headers, path: str, cert: dict[str, Any] | None) -> Peer:
        """The peer of a websocket upgrade request (see the module doc); AuthError if refused.

        A robot must present a certificate for its own id when the gateway has a client CA;
        a certificate for another robot is refused in any case.
        """
        token = request_token(single_header(headers, "Authorization"), path)
        cert_id = cert_robot_id(cert)
        if token is not None:
            peer = self.identify(token)
        elif self.logins.valid(cookie_value(headers)):
            peer = Peer("operator")
        elif cert_id is not None:
            peer = Peer("robot", cert_id)
        else:
            raise AuthError(401, "missing token (Authorization: Bearer <token> or ?token=)")
        if peer.role == "robot":
            if cert_id is None and self._robots_need_cert:
                raise AuthError(403, "a robot needs its client certificate")
            if cert_id is not None and cert_id != peer.robot_id:
                raise AuthError(403, f"the client certificate is for robot {cert_id}")
        return peer

    def operator_token(self, authorization: str | None) -> None:
        """Check an operator's ``Authorization: Bearer`` (the GUI login); AuthError if not."""
        peer = self.identify(request_token(authorization, ""))
        if peer.role != "operator":
            raise AuthError(403, "not an operator token")


def origin_allowed(headers: Headers, tls: bool, extra: list[str]) -> bool:
    """True if the request has no ``Origin`` (not a browser) or comes from the gateway's own
    origin (scheme and ``Host``) or one of ``extra``. AuthError(400) if either is repeated."""
    origin = single_header(headers, "Origin")
    if origin is None:
        return True
    host = single_header(headers, "Host")
    own = f"{'https' if tls else 'http'}://{host}" if host else None
    return origin == own or origin in extra
