"""The official VDA 5050 JSON schemas (read from ../shared/vda5050, never copied into the
project; ``FLEETGATE_VDA5050_DIR`` overrides the place) and a validator for every message."""

from __future__ import annotations

import json
import os
from functools import cache
from pathlib import Path
from typing import Any

import pytest

REPO = Path(__file__).resolve().parents[2]
SCHEMA_DIR = Path(os.environ.get("FLEETGATE_VDA5050_DIR", REPO / ".." / "shared" / "vda5050"))
FILES = {"order": "order.schema", "instantActions": "instantActions.schema",
         "state": "state.schema", "connection": "connection.schema",
         "visualization": "visualization.schema"}

needs_schemas = pytest.mark.skipif(not (SCHEMA_DIR / "2.1.0" / "json_schemas").is_dir(),
                                   reason="../shared/vda5050 (the official schemas) is absent")


@cache
def _validator(version: str, topic: str) -> Any:
    import jsonschema

    schema = json.loads((SCHEMA_DIR / version / "json_schemas" / FILES[topic]).read_text())
    return jsonschema.Draft202012Validator(schema,
                                           format_checker=jsonschema.FormatChecker())


def schema_errors(version: str, topic: str, payload: bytes | str | dict[str, Any]) -> list[str]:
    """Every way ``payload`` breaks the official schema of ``topic`` in ``version``."""
    data = payload if isinstance(payload, dict) else json.loads(payload)
    return [f"{'/'.join(map(str, e.absolute_path))}: {e.message}"
            for e in _validator(version, topic).iter_errors(data)]


def assert_valid(version: str, topic: str, payload: bytes | str | dict[str, Any]) -> None:
    """``payload`` validates against the official schema of ``topic`` in ``version``."""
    errors = schema_errors(version, topic, payload)
    assert not errors, f"{version} {topic}: {errors[:3]}"
