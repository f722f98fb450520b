"""How simulated robots reach a gateway over real websockets (shared by ``fleetgate demo``,
``fleetgate sim`` and the load benchmark)."""

from __future__ import annotations

import ssl
from collections.abc import Callable

from websockets.asyncio.client import connect as ws_connect

from sim_clients.fleet import ClientConnection, Connect


def websocket_connector(url: str, tls: Callable[[str], ssl.SSLContext | None] | None = None
                        ) -> Connect:
    """Opens ``url`` with a bearer token (no proxy, no compression); for ``wss://``,
    ``tls(token)`` is the SSL context of that token's connection (its client certificate)."""

    async def connect(token: str) -> ClientConnection:
        context = tls(token) if tls is not None else None
        return await ws_connect(url, additional_headers={"Authorization": f"Bearer {token}"},
                                proxy=None, compression=None, max_queue=None, ssl=context)

    return connect
