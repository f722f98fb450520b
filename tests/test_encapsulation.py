"""No module reaches into another module's private names (checked on the source, with ast).

In ``gateway/``, ``protocol/``, ``conformance/``, ``sim_clients/`` and ``experiments/``, a name
that starts with one underscore (not a dunder) is private to the module that defines it: another
module neither imports it (``from m import _x``) nor reads or writes it on an object
(``obj._x``, ``self._x`` inherited from another module's class included). A module "defines"
``_x`` if it binds it: a function, class or variable of that name, an assignment to
``self._x`` or ``cls._x``, or a parameter. What another module needs is public (a method, a
property, a snapshot of the state).
"""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("gateway", "protocol", "conformance", "sim_clients", "experiments")

ALLOWED = {
    "argparse._SubParsersAction": "the standard library has no public name for the type of "
                                  "add_subparsers(), which every command module annotates",
    "client._client": "aiomqtt's paho client (gateway/vda5050/broker.py publish): aiomqtt "
                      "has no publish that does not wait for each message's write (pinned "
                      "below 3 in pyproject.toml)",
    "os._exit": "the standard library's documented exit without cleanup (after a fork or a "
                "fatal error), public despite its underscore",
    "sys._getframe": "documented in the sys module (a CPython detail): the TLS handshake log "
                     "finds the peer of a failed handshake in asyncio's calling frame",
}


def _private(name: str) -> bool:
    return name.startswith("_") and not (name.startswith("__") and name.endswith("__"))


def _defined(tree: ast.AST) -> set[str]:
    """The private names a module binds (see the module doc)."""
    own: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef | ast.ClassDef):
            own.add(node.name)
        elif isinstance(node, ast.Name) and isinstance(node.ctx, ast.Store):
            own.add(node.id)
        elif isinstance(node, ast.arg):
            own.add(node.arg)
        elif (isinstance(node, ast.Attribute) and isinstance(node.ctx, ast.Store)
              and isinstance(node.value, ast.Name) and node.value.id in ("self", "cls")):
            own.add(node.attr)
    return {n for n in own if _private(n)}


def reaches(source: str) -> list[str]:
    """The other modules' private names ``source`` uses, as written."""
    tree = ast.parse(source)
    own = _defined(tree)
    found = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Attribute) and _private(node.attr) and node.attr not in own:
            written = ast.unparse(node)
            if written not in ALLOWED:
                found.append(written)
        elif isinstance(node, ast.ImportFrom):
            found += [f"from {node.module} import {a.name}" for a in node.names
                      if _private(a.name)]
    return found


def test_no_module_uses_another_modules_private_names() -> None:
    found = {}
    for package in PACKAGES:
        for path in sorted((ROOT / package).rglob("*.py")):
            hits = reaches(path.read_text())
            if hits:
                found[str(path.relative_to(ROOT))] = hits
    assert found == {}


def test_the_scan_finds_what_it_is_for() -> None:
    assert reaches("def f(ex):\n    return ex._sent\n") == ["ex._sent"]
    assert reaches("def f(ex):\n    ex._sent = [0]\n") == ["ex._sent"]
    assert reaches("from a.b import _helper\n") == ["from a.b import _helper"]
    # a mixin using what its partner class (in another module) defines
    assert reaches("class M:\n    def f(self):\n        self._time(1)\n") == ["self._time"]
    # what the module binds itself is its own
    own = ("class A:\n    def __init__(self):\n        self._x = 1\n"
           "    def same(self, other):\n        return other._x + self._y()\n"
           "    def _y(self):\n        return 2\n")
    assert reaches(own) == []
    assert reaches("import argparse\nx: argparse._SubParsersAction\n") == []
