"""The official VDA 5050 JSON schemas, read from a directory the user has (fleetgate carries no
copy): ``<dir>/<version>/json_schemas/<topic>.schema`` (2.0.0 names its factsheet schema
``factsheet.json``), and every way a message breaks the one of its topic and version."""

from __future__ import annotations

import json
import os
from functools import cache
from pathlib import Path
from typing import Any

DEFAULT_DIR = Path(os.environ.get(
    "FLEETGATE_VDA5050_DIR", Path(__file__).resolve().parents[2].parent / "shared" / "vda5050"))
"""``FLEETGATE_VDA5050_DIR``, else ``../shared/vda5050`` beside the checkout."""

TOPICS = ("order", "instantActions", "state", "connection", "visualization", "factsheet")


def schema_file(root: Path, version: str, topic: str) -> Path:
    """Where the schema of ``topic`` in ``version`` is under ``root``."""
    folder = root / version / "json_schemas"
    name = f"{topic}.schema"
    if topic == "factsheet" and not (folder / name).is_file():
        name = "factsheet.json"  # 2.0.0's spelling
    return folder / name


def have_schemas(root: Path, version: str) -> bool:
    """Whether ``root`` holds the schemas of ``version``."""
    return (root / version / "json_schemas").is_dir()


@cache
def _validator(root: Path, version: str, topic: str) -> Any:
    import jsonschema

    schema = json.loads(schema_file(root, version, topic).read_text())
    return jsonschema.Draft202012Validator(schema, format_checker=jsonschema.FormatChecker())


def schema_errors(version: str, topic: str, payload: bytes | str | dict[str, Any],
                  root: Path = DEFAULT_DIR) -> list[str]:
    """Every way ``payload`` breaks the official schema of ``topic`` in ``version`` (a
    payload that is no JSON object is one error)."""
    try:
        data = payload if isinstance(payload, dict) else json.loads(payload)
    except ValueError as exc:
        return [f"not JSON: {exc}"]
    return [f"{'/'.join(map(str, e.absolute_path)) or '(message)'}: {e.message}"
            for e in _validator(root, version, topic).iter_errors(data)]
