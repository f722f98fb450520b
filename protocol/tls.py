"""TLS for the websocket link (``wss://``): the identity a robot's client certificate carries,
and the client side's SSL context (robot_client and the simulated clients share it)."""

from __future__ import annotations

import ssl
from pathlib import Path

ROBOT_IDENTITY = "fleetgate:robot:"
"""A robot's client certificate names ``fleetgate:robot:<id>``: as a SAN URI (preferred) or as
its common name. The gateway binds the connection to that robot id (mutual TLS)."""


def robot_identity(robot_id: int) -> str:
    """The certificate identity of robot ``robot_id``."""
    return f"{ROBOT_IDENTITY}{robot_id}"


def client_context(ca: str | Path | None = None, cert: str | Path | None = None,
                   key: str | Path | None = None) -> ssl.SSLContext:
    """A client SSL context that verifies the gateway against ``ca`` (the system's CAs if
    None) and, with ``cert`` (and ``key``, if not in the same PEM), presents a client
    certificate. TLS 1.2 at least; the gateway's host name is checked. An OSError names the
    file that cannot be read (ssl's own errors do not)."""
    for what, path in (("CA", ca), ("certificate", cert), ("key", key)):
        if path is not None and not Path(path).is_file():
            raise FileNotFoundError(2, f"the TLS {what} file is missing", str(path))
    ctx = ssl.create_default_context(ssl.Purpose.SERVER_AUTH,
                                     cafile=str(ca) if ca is not None else None)
    ctx.minimum_version = ssl.TLSVersion.TLSv1_2
    if cert is not None:
        ctx.load_cert_chain(str(cert), str(key) if key is not None else None)
    return ctx
