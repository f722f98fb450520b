"""The gateway's TLS: a server SSL context from :class:`~gateway.server.config.TlsConfig`, whose
failed handshakes are logged.

asyncio drops a failed TLS handshake silently (it logs one only in debug mode), so a client
certificate from another CA, or plaintext sent to the TLS port, left no trace at all. The
context's SSL objects (:class:`LoggedSSLObject`, through the documented
``SSLContext.sslobject_class``) log each failed handshake at INFO with its reason and peer,
at most one line per :data:`HANDSHAKE_LOG_PERIOD_S` (the next line counts those left out): a
stranger cannot flood the log.
"""

from __future__ import annotations

import logging
import ssl
import sys
import time
from typing import Any

from gateway.server.config import TlsConfig

log = logging.getLogger("fleetgate.tls")

HANDSHAKE_LOG_PERIOD_S = 10.0
"""At most one log line about failed TLS handshakes per this many seconds."""


class HandshakeLog:
    """Failed handshakes, logged at most once per ``period_s`` (then with how many were left
    out since the last line)."""

    def __init__(self, period_s: float = HANDSHAKE_LOG_PERIOD_S) -> None:
        self.period_s = period_s
        self.failed = 0
        """Failed handshakes seen."""
        self._next_at = float("-inf")
        self._left_out = 0

    def failure(self, reason: str, peer: str) -> None:
        """One handshake failed for ``reason`` with ``peer``."""
        self.failed += 1
        now = time.monotonic()
        if now < self._next_at:
            self._left_out += 1
            return
        log.info("TLS handshake failed", extra={"peer": peer, "reason": reason,
                                                "not_logged_before": self._left_out})
        self._left_out, self._next_at = 0, now + self.period_s


HANDSHAKES = HandshakeLog()
"""The process's failed handshakes (one gateway per process)."""


def _handshake_transport() -> Any:
    """The socket transport of the connection whose handshake is being made: asyncio's SSL
    protocol (the caller's caller) holds it; None where it cannot be found."""
    frame = sys._getframe(2)
    for _ in range(4):
        transport = getattr(frame.f_locals.get("self"), "_transport", None)
        if transport is not None and hasattr(transport, "get_extra_info"):
            return transport
        if frame.f_back is None:
            break
        frame = frame.f_back
    return None


def _peer(transport: Any) -> str:
    """``host:port`` of ``transport``'s peer, or "unknown"."""
    peer = transport.get_extra_info("peername") if transport is not None else None
    return f"{peer[0]}:{peer[1]}" if peer else "unknown"


PLAIN_HTTP_HINT = b"this port speaks TLS: use https:// or wss://, not http:// or ws://\n"
PLAIN_HTTP_ANSWER = (b"HTTP/1.1 400 Bad Request\r\nContent-Type: text/plain\r\n"
                     b"Connection: close\r\nContent-Length: %d\r\n\r\n%s"
                     % (len(PLAIN_HTTP_HINT), PLAIN_HTTP_HINT))
"""What a plain HTTP request to the TLS port gets (instead of an empty reply)."""


class LoggedSSLObject(ssl.SSLObject):
    """An SSL object whose failed server handshake is told to :data:`HANDSHAKES`."""

    def do_handshake(self) -> None:
        """The handshake step; a failure (not a want-read/write) is logged, then raised."""
        try:
            super().do_handshake()
        except (ssl.SSLWantReadError, ssl.SSLWantWriteError):
            raise
        except ssl.SSLError as exc:
            reason = getattr(exc, "verify_message", None) or exc.reason or str(exc)
            transport = _handshake_transport()
            HANDSHAKES.failure(str(reason), _peer(transport))
            if exc.reason == "HTTP_REQUEST" and transport is not None:
                # a plain HTTP request: a hint, sent at once (the buffer is empty), then closed
                transport.write(PLAIN_HTTP_ANSWER)
            raise


class TlsError(ValueError):
    """The configured certificate, key or client CA cannot be loaded (one-line reason)."""


def server_context(cfg: TlsConfig) -> ssl.SSLContext:
    """TLS 1.2+ with the gateway's certificate; with ``client_ca``, client certificates are
    asked for (required if ``require_client_cert``) and verified against it."""
    ctx = ssl.create_default_context(ssl.Purpose.CLIENT_AUTH)
    ctx.minimum_version = ssl.TLSVersion.TLSv1_2
    try:
        ctx.load_cert_chain(str(cfg.cert), str(cfg.key))
        if cfg.client_ca is not None:
            ctx.load_verify_locations(cafile=str(cfg.client_ca))
            ctx.verify_mode = ssl.CERT_REQUIRED if cfg.require_client_cert else ssl.CERT_OPTIONAL
    except (OSError, ssl.SSLError) as exc:
        raise TlsError(f"cannot load the TLS files ({cfg.cert}, {cfg.key}, "
                       f"{cfg.client_ca}): {exc}") from None
    ctx.sslobject_class = LoggedSSLObject
    return ctx
