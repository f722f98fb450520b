"""The generated parts of docs/protocol.md: the message table and the JSON Schema, both from
the pydantic models, written between marker comments so the prose around them stays."""

from __future__ import annotations

import json
import re
from typing import Any

from protocol import OPERATOR_TYPES, ROBOT_TYPES, WORLD_TYPES, json_schema

TABLE = "GENERATED MESSAGE TABLE"
SCHEMA = "GENERATED SCHEMA"

TO_ROBOT = frozenset({"welcome", "action", "cancel", "pause", "resume", "error"})
TO_OPERATOR = frozenset({"snapshot", "event", "ok", "error"})
TO_WORLD = frozenset({"set_speed", "place_intruder", "error"})
_ENVELOPE = ("type", "v", "msg_id", "seq")


class StaleDocument(ValueError):
    """The document lacks the markers of a generated block."""


def _senders(kind: str) -> str:
    sent = [who for who, types in (("robot", ROBOT_TYPES), ("operator", OPERATOR_TYPES),
                                   ("world", WORLD_TYPES)) if kind in types]
    to = [who for who, types in (("robot", TO_ROBOT), ("operator", TO_OPERATOR),
                                 ("world", TO_WORLD)) if kind in types]
    parts = [f"{' / '.join(sent)} → gateway"] if sent else []
    if to:
        parts.append(f"gateway → {' / '.join(to)}")
    return "; ".join(parts)


def message_table() -> str:
    """A markdown table: each message type, who sends it, its required and optional fields."""
    schema = json_schema()
    rows = ["| type | direction | required fields | optional fields |", "|---|---|---|---|"]
    defs: dict[str, Any] = schema["$defs"]
    kinds = []
    for name, d in defs.items():
        kind = d.get("properties", {}).get("type", {}).get("const")
        if kind is not None:
            kinds.append((kind, name, d))
    for kind, _, d in sorted(kinds):
        required = [f for f in d.get("required", []) if f not in _ENVELOPE]
        optional = [f for f in d.get("properties", {}) if f not in _ENVELOPE
                    and f not in required]
        rows.append(f"| `{kind}` | {_senders(kind)} | {', '.join(required) or '—'} | "
                    f"{', '.join(optional) or '—'} |")
    return "\n".join(rows)


def schema_block() -> str:
    """The JSON Schema as a fenced block."""
    return "```json\n" + json.dumps(json_schema(), indent=2, sort_keys=True) + "\n```"


def _replace(text: str, marker: str, body: str) -> str:
    pattern = re.compile(rf"(<!-- BEGIN {marker} -->\n).*?(<!-- END {marker} -->)", re.S)
    if not pattern.search(text):
        raise StaleDocument(f"no '<!-- BEGIN {marker} -->' ... '<!-- END {marker} -->' block")
    return pattern.sub(lambda m: m[1] + body + "\n" + m[2], text, count=1)


def render(text: str) -> str:
    """``text`` (docs/protocol.md) with its generated blocks brought up to date."""
    return _replace(_replace(text, TABLE, message_table()), SCHEMA, schema_block())
