"""The JSON Schema of protocol v1 (what ``fleetgate protocol schema`` writes)."""

from __future__ import annotations

from typing import Any

from protocol.codec import MESSAGE_ADAPTER
from protocol.messages import PROTOCOL_VERSION


def json_schema() -> dict[str, Any]:
    """JSON Schema (draft 2020-12) of every message, as one ``oneOf`` on ``type``."""
    schema = MESSAGE_ADAPTER.json_schema(mode="validation")
    return {
        "$schema": "https://json-schema.org/draft/2020-12/schema",
        "$id": f"urn:fleetgate:protocol:v{PROTOCOL_VERSION}",
        "title": f"fleetgate protocol v{PROTOCOL_VERSION}",
        **schema,
    }
