"""The official VDA 5050 JSON schemas (read from ../shared/vda5050, never copied into the
project; ``FLEETGATE_VDA5050_DIR`` overrides the place) and an assertion for every message."""

from __future__ import annotations

from typing import Any

import pytest

from conformance.vda5050.schemas import DEFAULT_DIR, have_schemas, schema_errors

SCHEMA_DIR = DEFAULT_DIR

needs_schemas = pytest.mark.skipif(not have_schemas(SCHEMA_DIR, "2.1.0"),
                                   reason="../shared/vda5050 (the official schemas) is absent")


def assert_valid(version: str, topic: str, payload: bytes | str | dict[str, Any]) -> None:
    """``payload`` validates against the official schema of ``topic`` in ``version``."""
    errors = schema_errors(version, topic, payload)
    assert not errors, f"{version} {topic}: {errors[:3]}"
