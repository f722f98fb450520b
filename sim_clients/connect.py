"""How simulated robots reach a gateway over real websockets (shared by ``fleetgate demo``,
``fleetgate sim`` and the load benchmark)."""

from __future__ import annotations

from websockets.asyncio.client import connect as ws_connect

from sim_clients.fleet import ClientConnection, Connect


def websocket_connector(url: str) -> Connect:
    """Opens ``url`` with a bearer token (no proxy, no compression: loopback)."""

    async def connect(token: str) -> ClientConnection:
        return await ws_connect(url, additional_headers={"Authorization": f"Bearer {token}"},
                                proxy=None, compression=None, max_queue=None)

    return connect
