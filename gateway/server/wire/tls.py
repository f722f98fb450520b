"""The gateway's TLS: a server SSL context from :class:`~gateway.server.config.TlsConfig`."""

from __future__ import annotations

import ssl

from gateway.server.config import TlsConfig


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
    return ctx
