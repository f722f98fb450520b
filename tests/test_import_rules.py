"""DESIGN section 1: the layers import only what they may (checked on the source, statically)."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PURE_FORBIDDEN = ("gateway.server", "asyncio", "websockets", "pydantic", "time", "datetime",
                  "sim_clients", "protocol")


def _imports(path: Path) -> list[str]:
    tree = ast.parse(path.read_text(), filename=str(path))
    names: list[str] = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names.extend(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            names.append(node.module)
    return names


def _modules(package: str) -> list[Path]:
    return sorted((ROOT / package.replace(".", "/")).rglob("*.py"))


def _hits(name: str, prefixes: tuple[str, ...]) -> bool:
    return any(name == p or name.startswith(p + ".") for p in prefixes)


@pytest.mark.parametrize("package", ["gateway/planning", "gateway/execution"])
def test_pure_core_has_no_io_clock_or_server_imports(package: str) -> None:
    files = _modules(package)
    assert files, f"{package} has no modules"
    bad = [(f.name, n) for f in files for n in _imports(f) if _hits(n, PURE_FORBIDDEN)]
    assert bad == []


def test_protocol_imports_nothing_of_the_project() -> None:
    project = ("gateway", "robot_client", "sim_clients")
    bad = [(f.name, n) for f in _modules("protocol") for n in _imports(f) if _hits(n, project)]
    assert bad == []


def test_robot_client_imports_only_protocol() -> None:
    project = ("gateway", "sim_clients")
    bad = [(f.name, n) for f in _modules("robot_client") for n in _imports(f) if _hits(n, project)]
    assert bad == []


def test_nothing_imports_sim_clients() -> None:
    others = [*_modules("gateway"), *_modules("protocol"), *_modules("robot_client")]
    bad = [(f.name, n) for f in others for n in _imports(f) if _hits(n, ("sim_clients",))]
    assert bad == []
