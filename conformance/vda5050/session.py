"""The checker's side of a VDA 5050 vehicle under test: one MQTT connection playing the master
control, everything the vehicle publishes recorded (for the schema check), and the orders and
instant actions the checks send. Messages from the vehicle are read as JSON, not through
fleetgate's models: the checks say what they expect in terms of the standard's fields."""

from __future__ import annotations

import asyncio
import contextlib
import itertools
import json
import math
import os
import shlex
import signal
import ssl
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any
from urllib.parse import urlsplit

import aiomqtt

from conformance.report import CheckFailed, UsageProblem
from protocol.vda5050.topics import (
    QOS,
    RETAINED,
    VEHICLE_PUBLISHES,
    TopicName,
    VehicleTopics,
    major_of,
    timestamp,
)

Json = dict[str, Any]


@dataclass(frozen=True)
class Broker:
    """The MQTT broker: ``mqtt://HOST:PORT`` or ``mqtts://`` (TLS, CA ``cafile`` or the
    system's), with an optional user name and password."""

    url: str
    username: str | None = None
    password: str | None = None
    cafile: str | None = None

    def client(self, identifier: str) -> aiomqtt.Client:
        """An unconnected client (``async with``)."""
        parts = urlsplit(self.url)
        tls = parts.scheme == "mqtts"
        return aiomqtt.Client(parts.hostname or "", parts.port or (8883 if tls else 1883),
                              identifier=identifier, username=self.username,
                              password=self.password, keepalive=15, clean_session=True,
                              tls_context=ssl.create_default_context(cafile=self.cafile)
                              if tls else None)


@dataclass(frozen=True)
class VdaOptions:
    """Which vehicle, on which broker, and how to move it: ``step_m`` metres along +x of its
    map (the floor there must be free for three steps); ``command`` starts it ({broker},
    {manufacturer}, {serial}, {interface}, {version} substituted) and lets the last-will check
    kill it."""

    broker: Broker
    manufacturer: str
    serial: str
    version: str = "2.1.0"
    interface: str = "uagv"
    step_m: float = 1.0
    command: str | None = None
    schemas: Path | None = None
    timeout_s: float = 20.0
    will_timeout_s: float = 60.0


@dataclass
class Position:
    """Where the vehicle stood when the checks began (its ``agvPosition``)."""

    x: float
    y: float
    theta: float
    map_id: str


@dataclass
class VdaSession:
    """The checks' context: the MQTT connection, what the vehicle sent, and helpers."""

    options: VdaOptions
    received: list[tuple[str, bytes]] = field(default_factory=list)
    state: Json | None = None
    connection: Json | None = None
    factsheet: Json | None = None
    home: Position | None = None
    orders: dict[str, int] = field(default_factory=dict)
    """Order id -> its last ``orderUpdateId`` sent."""
    process: asyncio.subprocess.Process | None = None
    _client: aiomqtt.Client | None = None
    _changed: asyncio.Event = field(default_factory=asyncio.Event)
    _ids: itertools.count[int] = field(default_factory=itertools.count)
    _headers: dict[str, int] = field(default_factory=dict)

    @property
    def topics(self) -> VehicleTopics:
        """The vehicle's topics."""
        o = self.options
        return VehicleTopics(o.interface, major_of(o.version), o.manufacturer, o.serial)

    # ------------------------------------------------------------------ connection
    async def run(self, ready: asyncio.Event) -> None:
        """Connect, subscribe the vehicle's topics and record until cancelled."""
        try:
            async with self.options.broker.client(
                    f"fleetgate-conformance-{os.getpid()}") as client:
                self._client = client
                for name in VEHICLE_PUBLISHES:
                    await client.subscribe(self.topics.topic(name), qos=QOS[name])
                ready.set()
                async for message in client.messages:
                    self._record(str(message.topic).rsplit("/", 1)[-1], message.payload)
        except aiomqtt.MqttError as exc:
            raise UsageProblem(f"cannot reach the MQTT broker at {self.options.broker.url}: "
                               f"{exc}") from None

    def _record(self, name: str, payload: Any) -> None:
        data = payload if isinstance(payload, bytes) else str(payload).encode()
        self.received.append((name, data))
        try:
            msg = json.loads(data)
        except ValueError:
            return  # the schema check reports it
        if not isinstance(msg, dict):
            return
        if name == "state":
            self.state = msg
        elif name == "connection":
            self.connection = msg
        elif name == "factsheet":
            self.factsheet = msg
        self._changed.set()

    async def start_vehicle(self) -> None:
        """Run ``--command`` (if given)."""
        command = self.options.command
        if command is None:
            return
        o = self.options
        fields = {"{broker}": o.broker.url, "{manufacturer}": o.manufacturer,
                  "{serial}": o.serial, "{interface}": o.interface, "{version}": o.version}
        argv = []
        for part in shlex.split(command):
            for key, value in fields.items():
                part = part.replace(key, value)
            argv.append(part)
        try:
            self.process = await asyncio.create_subprocess_exec(
                *argv, stdout=asyncio.subprocess.DEVNULL, stderr=asyncio.subprocess.DEVNULL,
                start_new_session=True)
        except OSError as exc:
            raise UsageProblem(f"cannot run --command: {exc}") from None

    async def stop_vehicle(self) -> None:
        """Stop what ``--command`` started (its whole process group)."""
        proc, self.process = self.process, None
        if proc is None or proc.returncode is not None:
            return
        with contextlib.suppress(ProcessLookupError):
            os.killpg(proc.pid, signal.SIGTERM)
        try:
            await asyncio.wait_for(proc.wait(), 5.0)
        except TimeoutError:
            with contextlib.suppress(ProcessLookupError):
                os.killpg(proc.pid, signal.SIGKILL)
            await proc.wait()

    # ------------------------------------------------------------------ waiting
    async def until(self, what: str, pred: Callable[[VdaSession], bool],
                    timeout_s: float | None = None) -> None:
        """Wait until ``pred(self)`` holds after a message arrived; CheckFailed (saying
        ``what`` was expected) if it does not within the timeout."""
        deadline = time.monotonic() + (timeout_s or self.options.timeout_s)
        while not pred(self):
            self._changed.clear()
            left = deadline - time.monotonic()
            if left <= 0:
                raise CheckFailed(f"{what}: not within {timeout_s or self.options.timeout_s:g}"
                                  f" s (last state: {self.describe()})")
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(self._changed.wait(), left)

    async def holds(self, what: str, pred: Callable[[VdaSession], bool],
                    seconds: float) -> None:
        """``pred(self)`` holds after every message for ``seconds``; CheckFailed if not."""
        deadline = time.monotonic() + seconds
        while True:
            if not pred(self):
                raise CheckFailed(f"{what} (state: {self.describe()})")
            left = deadline - time.monotonic()
            if left <= 0:
                return
            self._changed.clear()
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(self._changed.wait(), left)

    def describe(self) -> str:
        """The last state in a few words."""
        s = self.state
        if s is None:
            return "none"
        errors = s.get("errors") or []
        last = errors[-1] if errors and isinstance(errors[-1], dict) else {}
        refs = {r.get("referenceKey"): r.get("referenceValue")
                for r in last.get("errorReferences") or [] if isinstance(r, dict)}
        return (f"order {s.get('orderId')!r}/{s.get('orderUpdateId')}, last node "
                f"{s.get('lastNodeId')!r}/{s.get('lastNodeSequenceId')}, driving "
                f"{s.get('driving')}, paused {s.get('paused')}, errors "
                f"{[e.get('errorType') for e in errors if isinstance(e, dict)]}"
                + (f", the last: {str(last.get('errorDescription', ''))[:200]!r} {refs}"
                   if last else ""))

    # ------------------------------------------------------------------ state queries
    def action_status(self, action_id: str) -> str | None:
        """The status the last state gives the action, if it lists it."""
        for a in (self.state or {}).get("actionStates", []):
            if a.get("actionId") == action_id:
                return str(a.get("actionStatus"))
        return None

    def errors_about(self, key: str, value: str) -> list[Json]:
        """The last state's errors that reference ``key`` = ``value``."""
        return [e for e in (self.state or {}).get("errors", [])
                if any(r.get("referenceKey") == key and r.get("referenceValue") == value
                       for r in e.get("errorReferences") or [])]

    def at(self, node_id: str) -> bool:
        """The vehicle's last node is ``node_id`` and it does not drive."""
        s = self.state or {}
        return s.get("lastNodeId") == node_id and not s.get("driving")

    # ------------------------------------------------------------------ sending
    async def publish(self, name: TopicName, body: Json) -> None:
        """Publish ``body`` (the header is added) on the vehicle's topic ``name``."""
        assert self._client is not None
        header_id = self._headers.get(name, -1) + 1
        self._headers[name] = header_id
        msg = {"headerId": header_id, "timestamp": timestamp(time.time()),
               "version": self.options.version, "manufacturer": self.options.manufacturer,
               "serialNumber": self.options.serial, **body}
        await self._client.publish(self.topics.topic(name), json.dumps(msg).encode(),
                                   qos=QOS[name], retain=name in RETAINED)

    async def instant(self, action_type: str) -> str:
        """Send one instant action (blocking HARD); its ``actionId``."""
        action_id = f"fgc-{action_type}-{next(self._ids)}"
        action = {"actionType": action_type, "actionId": action_id, "blockingType": "HARD"}
        body: Json = {"actions": [action]}
        if self.options.version.startswith("2.0."):
            # 2.0.0's schema spells actionName and actions, its text actionType and
            # instantActions (as fleetgate's master: both; protocol/vda5050/models.py)
            action["actionName"] = action_type
            body["instantActions"] = body["actions"]
        await self.publish("instantActions", body)
        return action_id

    def node(self, k: int, seq: int, released: bool) -> Json:
        """Node ``k`` steps along +x from where the vehicle stood, as sequence id ``seq``."""
        h = self.home
        if h is None:
            raise CheckFailed("no position of the vehicle (the state-request check failed)")
        return {"nodeId": f"fgc-n{k}", "sequenceId": seq, "released": released, "actions": [],
                "nodePosition": {"x": h.x + k * self.options.step_m, "y": h.y,
                                 "theta": h.theta, "mapId": h.map_id}}

    async def order(self, order_id: str, update_id: int, route: list[tuple[int, bool]],
                    first_seq: int = 0) -> None:
        """An order (or update) over nodes ``k`` (each released or not), sequence ids from
        ``first_seq``."""
        nodes = [self.node(k, first_seq + 2 * i, rel) for i, (k, rel) in enumerate(route)]
        edges = [{"edgeId": f"fgc-e{a[0]}-{b[0]}", "sequenceId": first_seq + 2 * i + 1,
                  "released": b[1], "startNodeId": f"fgc-n{a[0]}", "endNodeId": f"fgc-n{b[0]}",
                  "actions": []} for i, (a, b) in enumerate(itertools.pairwise(route))]
        self.orders[order_id] = update_id
        await self.publish("order", {"orderId": order_id, "orderUpdateId": update_id,
                                     "nodes": nodes, "edges": edges})

    def position(self) -> Position:
        """The vehicle's position now; CheckFailed if its state has none."""
        pos = (self.state or {}).get("agvPosition")
        if not isinstance(pos, dict) or not all(k in pos for k in ("x", "y", "mapId")):
            raise CheckFailed("the state has no agvPosition: the checks place their nodes "
                              "relative to it")
        theta = pos.get("theta", 0.0)
        return Position(float(pos["x"]), float(pos["y"]),
                        float(theta) if isinstance(theta, int | float) and math.isfinite(
                            theta) else 0.0, str(pos["mapId"]))
