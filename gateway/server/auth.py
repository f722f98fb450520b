"""Who is on the other end of a connection: token -> role (and robot id), checked at handshake."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal
from urllib.parse import parse_qs, urlsplit

from gateway.server.config import TokensConfig

Role = Literal["robot", "operator", "world"]


@dataclass(frozen=True)
class Peer:
    """An authenticated connection: its role and, for a robot, the robot id bound to its token."""

    role: Role
    robot_id: int | None = None

    def __str__(self) -> str:
        return f"robot {self.robot_id}" if self.role == "robot" else self.role


class AuthError(Exception):
    """The handshake is refused: ``status`` 401 (no token) or 403 (unknown token)."""

    def __init__(self, status: int, reason: str) -> None:
        super().__init__(reason)
        self.status = status
        self.reason = reason


class Authenticator:
    """Maps bearer tokens to peers according to the configured tokens."""

    def __init__(self, tokens: TokensConfig) -> None:
        self._robots = dict(tokens.robots)
        self._operators = frozenset(tokens.operators)
        self._world = frozenset(tokens.world)
        self._prefix = tokens.demo_robot_prefix

    def identify(self, token: str | None) -> Peer:
        """The peer a token stands for; AuthError if it is missing or unknown."""
        if not token:
            raise AuthError(401, "missing token (Authorization: Bearer <token> or ?token=)")
        if token in self._robots:
            return Peer("robot", self._robots[token])
        if token in self._operators:
            return Peer("operator")
        if token in self._world:
            return Peer("world")
        if self._prefix and token.startswith(self._prefix):
            rest = token[len(self._prefix):]
            if rest.isdigit() and len(rest) < 9:
                return Peer("robot", int(rest))
        raise AuthError(403, "unknown token")


def request_token(authorization: str | None, path: str) -> str | None:
    """The token of a handshake: ``Authorization: Bearer <t>`` header, else ``?token=<t>``."""
    if authorization:
        scheme, _, value = authorization.partition(" ")
        if scheme.lower() == "bearer" and value.strip():
            return value.strip()
    values = parse_qs(urlsplit(path).query).get("token")
    return values[0] if values else None
