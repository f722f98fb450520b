"""MQTT topics and headers of VDA 5050 (sections 6.2-6.4): topic names, QoS, retain, and the
timestamp format. Pure: times are arguments."""

from __future__ import annotations

import re
from dataclasses import dataclass
from datetime import UTC, datetime
from typing import Any, Literal

TopicName = Literal["order", "instantActions", "state", "visualization", "connection",
                    "factsheet"]

MASTER_PUBLISHES: tuple[TopicName, ...] = ("order", "instantActions")
VEHICLE_PUBLISHES: tuple[TopicName, ...] = ("state", "visualization", "connection",
                                            "factsheet")

QOS: dict[TopicName, int] = {"order": 0, "instantActions": 0, "state": 0, "visualization": 0,
                             "factsheet": 0, "connection": 1}
"""Section 6.2: QoS 0 everywhere but ``connection`` (QoS 1)."""

RETAINED: frozenset[TopicName] = frozenset({"connection", "factsheet"})
"""Sections 6.14 and 6.15: these topics are published with the retained flag."""

_SERIAL = re.compile(r"^[A-Za-z0-9_.:\-]{1,128}$")
_LEVEL = re.compile(r"^[^/$+#\x00]{1,128}$")


def check_level(value: str, what: str) -> str:
    """``value`` if it can be one topic level (no ``/``, ``$``, ``+``, ``#``); else ValueError."""
    if not _LEVEL.match(value):
        raise ValueError(f"{what} {value!r} cannot be an MQTT topic level "
                         "(1-128 characters, none of / $ + #)")
    return value


def check_serial(value: str) -> str:
    """``value`` if it is a valid serial number (A-Z a-z 0-9 _ . : -); else ValueError."""
    if not _SERIAL.match(value):
        raise ValueError(f"serial number {value!r} may only hold A-Z a-z 0-9 _ . : - "
                         "(1-128 characters)")
    return value


@dataclass(frozen=True, slots=True)
class VehicleTopics:
    """The topics of one vehicle: ``{interface}/{major}/{manufacturer}/{serial}/{topic}``."""

    interface: str
    major: str
    manufacturer: str
    serial: str

    def __post_init__(self) -> None:
        check_level(self.interface, "interface name")
        check_level(self.major, "major version")
        check_level(self.manufacturer, "manufacturer")
        check_serial(self.serial)

    @property
    def prefix(self) -> str:
        """Everything before the topic name, without the trailing slash."""
        return f"{self.interface}/{self.major}/{self.manufacturer}/{self.serial}"

    def topic(self, name: TopicName) -> str:
        """The full topic of ``name`` for this vehicle."""
        return f"{self.prefix}/{name}"


def major_of(version: str) -> str:
    """The topic's major version level of a protocol version: ``"2.1.0"`` -> ``"v2"``."""
    return "v" + version.split(".", 1)[0]


def split_topic(topic: str) -> tuple[str, str, str, str, str]:
    """``(interface, major, manufacturer, serial, name)`` of a topic; ValueError if it does not
    have five levels."""
    parts = topic.split("/")
    if len(parts) != 5:
        raise ValueError(f"not a VDA 5050 topic (five levels expected): {topic!r}")
    return parts[0], parts[1], parts[2], parts[3], parts[4]


def timestamp(epoch_s: float) -> str:
    """``epoch_s`` (seconds since 1970, UTC) as ``YYYY-MM-DDTHH:mm:ss.ffZ`` (section 6.4)."""
    moment = datetime.fromtimestamp(epoch_s, tz=UTC)
    return moment.strftime("%Y-%m-%dT%H:%M:%S.") + f"{moment.microsecond // 10000:02d}Z"


class Headers:
    """The header fields of the messages one side sends about one vehicle: ``headerId``
    counts from 0 per topic (section 6.4)."""

    def __init__(self, version: str, topics: VehicleTopics) -> None:
        self.version = version
        self.topics = topics
        self._ids: dict[str, int] = {}

    def __call__(self, topic: TopicName, now_s: float) -> dict[str, Any]:
        """The next header of ``topic`` at time ``now_s`` (model field names)."""
        header_id = self._ids.get(topic, -1) + 1
        self._ids[topic] = header_id
        return {"header_id": header_id, "timestamp": timestamp(now_s), "version": self.version,
                "manufacturer": self.topics.manufacturer, "serial_number": self.topics.serial}
