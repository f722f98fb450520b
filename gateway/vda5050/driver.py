"""The master control's MQTT connection: one client subscribes the ``state``, ``connection``
and ``factsheet`` topics of every configured vehicle, feeds each message to the vehicle's
:class:`protocol.vda5050.master.VehicleMaster`, and publishes what the masters send (QoS and
retain as the standard says). A malformed or unexpected message is one logged line, never an
error that stops the gateway. Times given to the masters are ``time.time()`` (wall clock: the
messages carry UTC timestamps)."""

from __future__ import annotations

import asyncio
import contextlib
import logging
import time
from collections.abc import Callable

import aiomqtt

from gateway.vda5050.broker import BrokerConfig, publish
from protocol.vda5050.master import Effect, Publish, VehicleMaster
from protocol.vda5050.models import Connection, Factsheet, State, parse
from protocol.vda5050.topics import QOS, VEHICLE_PUBLISHES, split_topic

log = logging.getLogger("fleetgate.vda5050")

MAX_PAYLOAD = 256 * 1024
"""Larger messages from a vehicle are dropped (logged)."""

TICK_S = 0.5
"""How often the masters may resend what a vehicle has not acted on."""


class MasterClient:
    """Runs the masters of the configured vehicles over one MQTT connection.

    ``on_effect`` receives every effect that is not a publish (reports, link changes), with
    the master it came from; ``on_state`` hears of every ``state`` a master took in. Call
    :meth:`flush` after feeding a master from outside (a release, a cancel) so that what it
    sends goes out.
    """

    def __init__(self, broker: BrokerConfig, masters: list[VehicleMaster],
                 on_effect: Callable[[VehicleMaster, Effect], None], *,
                 on_state: Callable[[VehicleMaster], None] | None = None,
                 identifier: str = "fleetgate-master") -> None:
        self.broker = broker
        self.masters = {m.topics.prefix: m for m in masters}
        self.on_effect = on_effect
        self.on_state = on_state
        self.identifier = identifier
        self.dropped = 0
        self.connected = asyncio.Event()
        self._out: asyncio.Queue[tuple[VehicleMaster, Publish]] = asyncio.Queue()

    def flush(self, master: VehicleMaster) -> None:
        """Hand on what ``master`` has to send or report."""
        for effect in master.drain():
            if isinstance(effect, Publish):
                self._out.put_nowait((master, effect))
            else:
                self.on_effect(master, effect)

    async def run(self) -> None:
        """Connect, subscribe and serve until cancelled."""
        async with self.broker.client(self.identifier, on_message=self._receive) as client:
            for master in self.masters.values():
                for name in VEHICLE_PUBLISHES:
                    if name != "visualization":
                        await client.subscribe(master.topics.topic(name), qos=QOS[name])
            self.connected.set()
            writer = asyncio.create_task(self._write(client))
            ticker = asyncio.create_task(self._tick())
            try:
                async for _ in client.messages:  # ends with the connection: messages go
                    pass  # to _receive as they are read (BrokerConfig.client's on_message)
            finally:
                writer.cancel()
                ticker.cancel()
                for task in (writer, ticker):
                    with contextlib.suppress(asyncio.CancelledError):
                        await task

    async def _write(self, client: aiomqtt.Client) -> None:
        """Hand everything queued to the client at each wake-up (one batch, not one loop
        round trip per message)."""
        out = self._out
        while True:
            master, item = await out.get()
            while True:
                publish(client, master.topics.topic(item.topic), item.topic, item.message)
                if out.empty():
                    break
                master, item = out.get_nowait()

    async def _tick(self) -> None:
        while True:
            await asyncio.sleep(TICK_S)
            now = time.time()
            for master in self.masters.values():
                master.tick(now)
                self.flush(master)

    def _receive(self, message: aiomqtt.Message) -> None:
        topic = str(message.topic)
        try:
            *prefix, name = split_topic(topic)
            master = self.masters.get("/".join(prefix))
            if master is None:
                raise ValueError("not a configured vehicle")
            payload = message.payload
            if not isinstance(payload, bytes | str) or len(payload) > MAX_PAYLOAD:
                raise ValueError("payload is not a JSON text of at most 256 KiB")
            msg = parse(name, payload)
            if isinstance(msg, Factsheet):
                master.receive_factsheet(msg)
            elif isinstance(msg, State):
                master.receive_state(msg, time.time())
                if self.on_state is not None:
                    self.on_state(master)
            elif isinstance(msg, Connection):
                master.receive_connection(msg)
            else:
                raise ValueError(f"a vehicle does not publish {name}")
        except ValueError as exc:
            self.dropped += 1
            log.warning("dropped a VDA 5050 message", extra={
                "topic": topic[:200], "error": str(exc).splitlines()[0][:300]})
            return
        self.flush(master)
