"""How fleetgate and its simulated vehicles reach an MQTT broker: ``mqtt://host:port`` or, over
TLS, ``mqtts://host:port``, with optional username and password (see docs/vda5050.md)."""

from __future__ import annotations

import asyncio
import ssl
from collections.abc import Callable
from pathlib import Path
from typing import Annotated
from urllib.parse import urlsplit

import aiomqtt
import paho.mqtt.client as paho
from pydantic import BaseModel, ConfigDict, Field, SecretStr, field_validator

from protocol.vda5050.models import Header, dump
from protocol.vda5050.topics import QOS, RETAINED, TopicName


class BrokerConfig(BaseModel):
    """Where the broker is and how to log in."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    url: str = "mqtt://127.0.0.1:1883"
    username: str | None = None
    password: SecretStr | None = None
    ca_file: Path | None = None
    """CA bundle that signs the broker's certificate (mqtts; the system's by default)."""
    cert_file: Path | None = None
    key_file: Path | None = None
    keepalive_s: Annotated[int, Field(ge=5, le=3600)] = 15
    """MQTT keep-alive: the broker sends a vehicle's last will this long (x 1.5) after it
    went silent; section 6.14 suggests about 15 s."""

    @field_validator("url")
    @classmethod
    def _url(cls, value: str) -> str:
        parts = urlsplit(value)
        if parts.scheme not in ("mqtt", "mqtts") or not parts.hostname:
            raise ValueError(f"broker url must be mqtt://host[:port] or mqtts://host[:port], "
                             f"got {value!r}")
        if parts.path not in ("", "/") or parts.query or parts.username or parts.password:
            raise ValueError("broker url holds only scheme, host and port (username and "
                             "password are separate settings)")
        return value

    @property
    def host(self) -> str:
        """The broker's host name or address."""
        host = urlsplit(self.url).hostname
        assert host is not None
        return host

    @property
    def tls(self) -> bool:
        """Whether the connection uses TLS (``mqtts://``)."""
        return urlsplit(self.url).scheme == "mqtts"

    @property
    def port(self) -> int:
        """The broker's port (1883, or 8883 with TLS, unless given)."""
        return urlsplit(self.url).port or (8883 if self.tls else 1883)

    def tls_context(self) -> ssl.SSLContext | None:
        """The client TLS context (certificate checked against ``ca_file`` or the system's
        CAs), or None without TLS."""
        if not self.tls:
            return None
        context = ssl.create_default_context(
            cafile=str(self.ca_file) if self.ca_file is not None else None)
        if self.cert_file is not None:
            context.load_cert_chain(str(self.cert_file),
                                    str(self.key_file) if self.key_file else None)
        return context

    def client(self, identifier: str, will: aiomqtt.Will | None = None,
               on_message: Callable[[aiomqtt.Message], None] | None = None) -> aiomqtt.Client:
        """An (unconnected) client; use it as ``async with``. ``on_message``: every message
        received goes to it as it is read (see :func:`dispatching`), not to
        ``client.messages``."""
        return aiomqtt.Client(
            self.host, self.port, identifier=identifier, username=self.username,
            password=self.password.get_secret_value() if self.password else None,
            will=will, keepalive=self.keepalive_s, tls_context=self.tls_context(),
            clean_session=True,
            queue_type=None if on_message is None else dispatching(on_message))


def dispatching(handler: Callable[[aiomqtt.Message], None]
                ) -> type[asyncio.Queue[aiomqtt.Message]]:
    """A ``queue_type`` for ``aiomqtt.Client`` that hands each received message to
    ``handler`` at once instead of queueing it. Iterating ``client.messages`` costs a task and
    an ``asyncio.wait`` per message; with this queue it yields nothing and only ends (with
    MqttError) when the connection is lost, so ``async for _ in client.messages: pass`` waits
    for that."""

    class Dispatch(asyncio.Queue[aiomqtt.Message]):
        def put_nowait(self, item: aiomqtt.Message) -> None:
            handler(item)

    return Dispatch


def will(topic: str, message: Header) -> aiomqtt.Will:
    """The last will: ``message`` (a CONNECTIONBROKEN ``connection``), QoS 1, retained."""
    return aiomqtt.Will(topic, dump(message), qos=QOS["connection"], retain=True)


def publish(client: aiomqtt.Client, topic: str, name: TopicName, message: Header) -> None:
    """Queue ``message`` for ``topic`` with the QoS and retain flag the standard sets for topic
    ``name``; the client's socket writer sends it (in order, with whatever else is queued).

    Not awaited: ``aiomqtt.Client.publish`` waits until paho has written each message, even
    at QoS 0, one event-loop round trip and a task per message; a master sending hundreds a
    second fell behind and its queue grew with the run's length. paho's own publish queues
    the packet and aiomqtt's writer callback flushes the queue when the socket is writable
    (QoS 1 is retried by paho). MqttCodeError if the client is not connected."""
    info = client._client.publish(topic, dump(message), QOS[name], name in RETAINED)
    if info.rc != paho.MQTT_ERR_SUCCESS:
        raise aiomqtt.MqttCodeError(info.rc, "Could not publish message")
