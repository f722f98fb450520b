"""DESIGN section 1: the layers import only what they may (checked on the source, statically).

Every ``import``/``from ... import`` of every module is read with :mod:`ast`, including imports
inside functions and ``TYPE_CHECKING`` blocks; relative imports are resolved against the
module's package.
"""

from __future__ import annotations

import ast
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PROJECT = ("gateway", "protocol", "robot_client", "sim_clients", "experiments", "tracecheck",
           "conformance", "fleetgate", "tests", "bench")
PURE_FORBIDDEN = ("gateway.server", "gateway.runtime", "gateway.commands", "gateway.cli",
                  "asyncio", "websockets", "pydantic", "time", "datetime", "sim_clients",
                  "experiments", "tracecheck", "protocol")
CLI = ("gateway.cli", "gateway.commands", "gateway.__main__", "fleetgate.__main__")
"""The ``fleetgate`` command's own modules (plugins' command modules: see :func:`_is_cli`)."""


def _module_name(path: Path) -> str:
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def _imports(path: Path) -> list[str]:
    """Absolute names of every module ``path`` imports (relative imports resolved)."""
    tree = ast.parse(path.read_text(), filename=str(path))
    package = _module_name(path).split(".")
    if path.name != "__init__.py":
        package.pop()
    names: list[str] = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names.extend(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            base = package[:len(package) - node.level + 1] if node.level else []
            module = ".".join([*base, *([node.module] if node.module else [])])
            names.append(module)
            names.extend(f"{module}.{alias.name}" for alias in node.names)
    return names


def _modules(*packages: str) -> list[Path]:
    files: list[Path] = []
    for package in packages:
        path = ROOT / package.replace(".", "/")
        files.extend(sorted(path.rglob("*.py")) if path.is_dir() else [path.with_suffix(".py")])
    return files


def _hits(name: str, prefixes: tuple[str, ...]) -> bool:
    return any(name == p or name.startswith(p + ".") for p in prefixes)


def _violations(files: list[Path], forbidden: tuple[str, ...]) -> list[tuple[str, str]]:
    assert files, "no modules found"
    return sorted({(_module_name(f), n) for f in files for n in _imports(f)
                   if _hits(n, forbidden)})


def _is_cli(module: str) -> bool:
    """Modules of the ``fleetgate`` command: gateway's, and the command modules that
    ``sim_clients`` and ``experiments`` plug in through the ``fleetgate.commands`` entry point."""
    last = module.rsplit(".", 1)[-1]
    return _hits(module, CLI) or (module.split(".")[0] in ("sim_clients", "experiments")
                                  and (last == "commands" or last.startswith("cmd_")))


@pytest.mark.parametrize("package", ["gateway/planning", "gateway/execution"])
def test_pure_core_has_no_io_clock_or_server_imports(package: str) -> None:
    assert _violations(_modules(package), PURE_FORBIDDEN) == []


USERIO = "fleetgate.userio"
"""How every command writes the files a user asked for and how it ends (exit codes, one line
for Ctrl-C, a closed pipe, a full disk): standard library only and no fleetgate logic, so the
independent checker, the robot client and the conformance checker use it too."""


def _outside_userio(violations: list[tuple[str, str]]) -> list[tuple[str, str]]:
    return [(m, n) for m, n in violations if not _hits(n, (USERIO,)) and n != "fleetgate"]


def test_userio_uses_the_standard_library_only() -> None:
    names = {n.split(".")[0] for f in _modules(USERIO) for n in _imports(f)
             if not _hits(n, (USERIO,)) and n != "fleetgate"}
    assert sorted(n for n in names if n not in sys.stdlib_module_names
                  and n != "__future__") == []


def test_protocol_imports_nothing_of_the_project() -> None:
    assert _violations(_modules("protocol"), tuple(p for p in PROJECT if p != "protocol")) == []


def test_robot_client_imports_only_protocol() -> None:
    others = tuple(p for p in PROJECT if p not in ("protocol", "robot_client"))
    assert _outside_userio(_violations(_modules("robot_client"), others)) == []


def test_gateway_imports_neither_simulator_nor_experiments() -> None:
    above = ("sim_clients", "experiments", "tracecheck", "tests", "bench")
    assert _violations(_modules("gateway", "protocol", "robot_client"), above) == []


def test_simulator_does_not_import_experiments() -> None:
    assert _violations(_modules("sim_clients"), ("experiments", "tests", "bench")) == []


def test_runtime_helpers_sit_below_the_drivers_and_the_cli() -> None:
    drivers = ("gateway.server", *CLI, "sim_clients", "experiments")
    assert _violations(_modules("gateway/runtime"), drivers) == []


def test_discrete_event_simulator_has_no_asyncio_server() -> None:
    des = _modules(*(f"sim_clients/{m}" for m in ("des", "robot", "world", "intruder")))
    assert _violations(des, ("gateway.server", "asyncio", "websockets")) == []


def test_no_package_imports_the_cli() -> None:
    files = _modules("gateway", "protocol", "robot_client", "sim_clients", "experiments",
                     "tracecheck", "fleetgate", "bench")
    bad = [(m, n) for m, n in _violations(files, CLI) if not _is_cli(m)]
    assert bad == []
    # The command modules share the CLI's helpers, but nothing imports the entry point back.
    entries = ("gateway.__main__", "fleetgate.__main__")
    back = [(m, n) for m, n in _violations(files, ("gateway.cli",)) if m not in entries]
    assert back == []
    plugins = [(m, n) for m, n in _violations(files, ("sim_clients", "experiments"))
               if _is_cli(n) and not _is_cli(m)]
    assert plugins == []


def test_tracecheck_imports_nothing_of_the_project() -> None:
    others = tuple(p for p in PROJECT if p != "tracecheck")
    assert _outside_userio(_violations(_modules("tracecheck"), others)) == []


def test_benchmarks_do_not_import_tests() -> None:
    assert _violations(_modules("bench"), ("tests",)) == []


def test_planning_never_imports_execution() -> None:
    assert _violations(_modules("gateway/planning"), ("gateway.execution",)) == []


def test_the_two_execution_modes_do_not_import_each_other() -> None:
    oneshot, lifelong = "gateway.execution.oneshot", "gateway.execution.lifelong"
    assert _violations(_modules(oneshot), (lifelong,)) == []
    assert _violations(_modules(lifelong), (oneshot,)) == []


def test_the_shared_execution_modules_import_neither_mode() -> None:
    shared = [f for f in _modules("gateway/execution") if f.parent.name == "execution"]
    modes = ("gateway.execution.oneshot", "gateway.execution.lifelong")
    assert _violations(shared, modes) == []


def test_conformance_kit_imports_only_protocol() -> None:
    others = tuple(p for p in PROJECT if p not in ("protocol", "conformance"))
    assert _outside_userio(_violations(_modules("conformance"), others)) == []


def test_the_wire_knows_no_engine_run_or_execution() -> None:
    above = ("gateway.server.engine", "gateway.server.runs", "gateway.server.operator_commands",
             "gateway.server.gateway", "gateway.execution")
    assert _violations(_modules("gateway/server/wire"), above) == []



def test_runs_and_task_api_never_import_the_engine() -> None:
    files = _modules("gateway/server/runs", "gateway/server/task_api")
    assert _violations(files, ("gateway.server.engine", "gateway.server.operator_commands",
                               "gateway.server.gateway")) == []


def test_the_engine_imports_neither_execution_mode() -> None:
    modes = ("gateway.execution.oneshot", "gateway.execution.lifelong")
    engine = _modules("gateway.server.engine", "gateway.server.operator_commands")
    assert _violations(engine, modes) == []


def _import_graph(files: list[Path]) -> dict[str, set[str]]:
    """Which of ``files`` each of them imports (an import names the longest module it
    reaches; packages' ``__init__`` left out)."""
    names = {_module_name(f): f for f in files if f.name != "__init__.py"}
    graph: dict[str, set[str]] = {}
    for name, f in names.items():
        targets = set()
        for imported in _imports(f):
            parts = imported.split(".")
            reached = [".".join(parts[:k]) for k in range(len(parts), 0, -1)
                       if ".".join(parts[:k]) in names]
            targets.update(reached[:1])
        graph[name] = targets - {name}
    return graph


def _circles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The import circles of ``graph``: its strongly connected components of more than one
    module (Tarjan's algorithm)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    found: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        for w in sorted(graph[v]):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component: list[str] = []
            while not component or component[-1] != v:
                component.append(stack.pop())
            if len(component) > 1:
                found.append(sorted(component))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return sorted(found)


def test_no_import_circle_inside_gateway() -> None:
    # TYPE_CHECKING imports count: a circle hidden behind them is still a circle
    graph = _import_graph(_modules("gateway"))
    assert "gateway.server.engine" in graph["gateway.server.gateway"]
    assert _circles(graph) == []


def test_the_circle_finder_finds_circles() -> None:
    graph = {"a": {"b"}, "b": {"c"}, "c": {"a", "d"}, "d": set(), "e": {"f"}, "f": {"e"}}
    assert _circles(graph) == [["a", "b", "c"], ["e", "f"]]
    assert _circles({"a": {"b"}, "b": set()}) == []
