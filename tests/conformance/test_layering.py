"""The conformance checker is the vendor-facing piece: it imports only `protocol`, websockets
and the standard library (and `fleetgate.userio`, how every command writes files and ends, on
the standard library alone; checked on the source, statically). Its VDA 5050 mode
(`conformance/vda5050/`) speaks MQTT and reads JSON schemas: aiomqtt and jsonschema too."""

from __future__ import annotations

import ast
import sys
from pathlib import Path

PACKAGE = Path(__file__).resolve().parents[2] / "conformance"


def test_conformance_imports_only_protocol_websockets_and_stdlib() -> None:
    files = sorted(PACKAGE.rglob("*.py"))
    assert PACKAGE / "vda5050" / "session.py" in files
    bad = []
    for f in files:
        extra = ("aiomqtt", "jsonschema") if f.parent.name == "vda5050" else ()
        for node in ast.walk(ast.parse(f.read_text())):
            names = ([a.name for a in node.names] if isinstance(node, ast.Import) else
                     [node.module] if isinstance(node, ast.ImportFrom) and node.module
                     and node.level == 0 else [])
            for name in names:
                top = name.split(".")[0]
                ok = (top in ("protocol", "websockets", *extra)
                      or top in sys.stdlib_module_names
                      or name.startswith(("conformance", "fleetgate.userio")))
                if not ok:
                    bad.append((str(f.relative_to(PACKAGE)), name))
    assert bad == []
