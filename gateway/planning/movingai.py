"""Readers and writers for MovingAI ``.map`` / ``.scen`` files and mapf-IR instance files.

Formats (see ``shared/maps/SOURCES.md``):

* ``.map``: header ``type octile``, ``height H``, ``width W``, ``map``, then H rows of W tiles;
  ``.`` ``G`` ``S`` are free, ``@`` ``O`` ``T`` ``W`` blocked.
* ``.scen``: ``version 1``, then one agent per line, TAB-separated:
  ``bucket map W H start_x start_y goal_x goal_y optimal_length``.
* mapf-IR (Kei18): ``key=value`` header lines (``map_file=`` is required), then one agent per
  line as ``start_x,start_y,goal_x,goal_y``.

Every reader raises :class:`MapFormatError` with a one-line ``file:line: reason`` message.
Checks that need the grid (cells on obstacles, duplicates, reachability) live in
:mod:`gateway.planning.instance`.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from gateway.planning.grid import Cell, Grid

FREE_TILES = frozenset(".GS")
"""Tiles a robot may stand on."""
BLOCKED_TILES = frozenset("@OTW")
"""Obstacle tiles."""

_SCEN_FIELDS = ("bucket", "map", "width", "height", "start_x", "start_y", "goal_x", "goal_y",
                "optimal_length")


class MapFormatError(ValueError):
    """Malformed map, scenario or instance input; the message is ``file:line: reason``."""

    def __init__(self, source: str, line: int, reason: str) -> None:
        super().__init__(f"{source}:{line}: {reason}")
        self.source = source
        self.line = line
        self.reason = reason


@dataclass(frozen=True)
class AgentSpec:
    """One agent of a scenario or instance file; ``line`` is where it was read (1-based)."""

    start: Cell
    goal: Cell
    line: int = field(default=0, compare=False)


@dataclass(frozen=True)
class ScenEntry(AgentSpec):
    """One line of a MovingAI ``.scen`` file.

    ``optimal_length`` is whatever the file says (MovingAI's own files give the octile,
    8-connected distance, which is not a 4-connected lower bound).
    """

    bucket: int = 0
    map_name: str = ""
    width: int = 0
    height: int = 0
    optimal_length: float = 0.0


@dataclass(frozen=True)
class AgentFile:
    """The agents of one scenario or instance file, in file order.

    ``map_file`` is the map the file names (``.scen`` lines name one too; empty if none) and
    ``last_line`` the number of the file's last line, for errors about the whole file.
    """

    source: str
    agents: tuple[AgentSpec, ...]
    last_line: int
    map_file: str = ""
    header: tuple[tuple[str, str], ...] = ()


# ----------------------------------------------------------------------------------- maps


def _header_value(source: str, lineno: int, line: str, key: str) -> str:
    parts = line.split()
    if len(parts) != 2 or parts[0] != key:
        raise MapFormatError(source, lineno, f"bad header: expected '{key} <value>', got {line!r}")
    return parts[1]


def _positive_int(source: str, lineno: int, text: str, what: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise MapFormatError(source, lineno,
                             f"bad header: {what} {text!r} is not an integer") from None
    if value <= 0:
        raise MapFormatError(source, lineno, f"bad header: {what} must be positive, got {value}")
    return value


def parse_map(text: str, source: str = "<map>", name: str = "") -> Grid:
    """Parse the text of a MovingAI ``.map`` file into a :class:`Grid`."""
    lines = text.splitlines()
    if len(lines) < 4:
        raise MapFormatError(source, len(lines) + 1,
                             "bad header: expected 'type', 'height', 'width' and 'map' lines")
    _header_value(source, 1, lines[0], "type")
    dims: dict[str, int] = {}
    for lineno in (2, 3):
        parts = lines[lineno - 1].split()
        if len(parts) != 2 or parts[0] not in ("height", "width") or parts[0] in dims:
            raise MapFormatError(source, lineno, f"bad header: expected 'height <H>' and "
                                 f"'width <W>', got {lines[lineno - 1]!r}")
        dims[parts[0]] = _positive_int(source, lineno, parts[1], parts[0])
    if lines[3].strip() != "map":
        raise MapFormatError(source, 4, f"bad header: expected 'map', got {lines[3]!r}")
    height, width = dims["height"], dims["width"]
    rows = lines[4:]
    while rows and not rows[-1].strip():
        rows.pop()
    if len(rows) < height:
        raise MapFormatError(source, 4 + len(rows),
                             f"wrong row count: {len(rows)} rows, header says height {height}")
    if len(rows) > height:
        raise MapFormatError(source, 5 + height,
                             f"wrong row count: more than {height} rows (header height)")
    free = np.zeros((height, width), dtype=bool)
    for y, row in enumerate(rows):
        lineno = 5 + y
        if len(row) != width:
            raise MapFormatError(source, lineno,
                                 f"ragged row: {len(row)} tiles, header says width {width}")
        for x, tile in enumerate(row):
            if tile in FREE_TILES:
                free[y, x] = True
            elif tile not in BLOCKED_TILES:
                raise MapFormatError(source, lineno, f"unknown tile {tile!r} at column {x}")
    return Grid(free, name=name)


def read_map(path: str | Path) -> Grid:
    """Read a ``.map`` file; the grid is named after the file (``random-32-32-20.map``)."""
    p = Path(path)
    return parse_map(p.read_text(encoding="utf-8"), source=str(p), name=p.name)


def format_map(grid: Grid) -> str:
    """The ``.map`` text of a grid (``.`` free, ``@`` blocked)."""
    rows = ["".join("." if f else "@" for f in row) for row in grid.free.tolist()]
    return "\n".join(["type octile", f"height {grid.height}", f"width {grid.width}", "map",
                      *rows]) + "\n"


def write_map(grid: Grid, path: str | Path) -> None:
    """Write a grid as a ``.map`` file."""
    Path(path).write_text(format_map(grid), encoding="utf-8")


# ------------------------------------------------------------------------------ scenarios


def _int_field(source: str, lineno: int, text: str, what: str, kind: str) -> int:
    try:
        return int(text)
    except ValueError:
        raise MapFormatError(source, lineno,
                             f"bad {kind}: {what} {text!r} is not an integer") from None


def _scen_entry(source: str, lineno: int, line: str) -> ScenEntry:
    parts = line.split("\t") if "\t" in line else line.split()
    parts = [p.strip() for p in parts]
    if len(parts) != len(_SCEN_FIELDS):
        raise MapFormatError(source, lineno, f"bad scenario line: {len(parts)} fields, expected "
                             f"{len(_SCEN_FIELDS)} ({' '.join(_SCEN_FIELDS)})")
    ints = [_int_field(source, lineno, parts[i], _SCEN_FIELDS[i], "scenario line")
            for i in (0, 2, 3, 4, 5, 6, 7)]
    try:
        optimal = float(parts[8])
    except ValueError:
        raise MapFormatError(source, lineno, f"bad scenario line: optimal_length {parts[8]!r} "
                             "is not a number") from None
    bucket, width, height, sx, sy, gx, gy = ints
    return ScenEntry(start=(sx, sy), goal=(gx, gy), line=lineno, bucket=bucket,
                     map_name=parts[1], width=width, height=height, optimal_length=optimal)


def parse_scen(text: str, source: str = "<scen>") -> AgentFile:
    """Parse the text of a MovingAI ``.scen`` file (agents are :class:`ScenEntry`)."""
    lines = text.splitlines()
    first = lines[0].split() if lines else []
    if len(first) != 2 or first[0] != "version":
        raise MapFormatError(source, 1, f"bad header: expected 'version 1', got "
                             f"{lines[0] if lines else ''!r}")
    entries = [_scen_entry(source, n, line)
               for n, line in enumerate(lines[1:], start=2) if line.strip()]
    map_file = entries[0].map_name if entries else ""
    return AgentFile(source, tuple(entries), max(len(lines), 1), map_file)


def read_scen(path: str | Path) -> AgentFile:
    """Read a ``.scen`` file."""
    p = Path(path)
    return parse_scen(p.read_text(encoding="utf-8"), source=str(p))


def format_scen(entries: Sequence[ScenEntry]) -> str:
    """The ``.scen`` text of the given lines (``optimal_length`` with 8 decimals, as MovingAI)."""
    out = ["version 1"]
    for e in entries:
        fields = (e.bucket, e.map_name, e.width, e.height, *e.start, *e.goal,
                  f"{e.optimal_length:.8f}")
        out.append("\t".join(str(f) for f in fields))
    return "\n".join(out) + "\n"


def write_scen(entries: Sequence[ScenEntry], path: str | Path) -> None:
    """Write a ``.scen`` file."""
    Path(path).write_text(format_scen(entries), encoding="utf-8")


# ---------------------------------------------------------------------- mapf-IR instances


def _mapf_ir_agent(source: str, lineno: int, line: str) -> AgentSpec:
    parts = line.split(",")
    if len(parts) != 4:
        raise MapFormatError(source, lineno, f"bad agent line: expected "
                             f"'start_x,start_y,goal_x,goal_y', got {line!r}")
    names = ("start_x", "start_y", "goal_x", "goal_y")
    sx, sy, gx, gy = (_int_field(source, lineno, p.strip(), n, "agent line")
                      for p, n in zip(parts, names, strict=True))
    return AgentSpec(start=(sx, sy), goal=(gx, gy), line=lineno)


def parse_mapf_ir(text: str, source: str = "<instance>") -> AgentFile:
    """Parse a mapf-IR instance file; ``map_file`` is its ``map_file=`` header value."""
    lines = text.splitlines()
    header: list[tuple[str, str]] = []
    agents: list[AgentSpec] = []
    for lineno, raw in enumerate(lines, start=1):
        line = raw.strip()
        if not line:
            continue
        if "=" in line:
            if agents:
                raise MapFormatError(source, lineno, f"bad header: {line!r} after agent lines")
            key, value = (s.strip() for s in line.split("=", 1))
            header.append((key, value))
        else:
            agents.append(_mapf_ir_agent(source, lineno, line))
    values = dict(header)
    if not values.get("map_file"):
        raise MapFormatError(source, 1, "bad header: no 'map_file=' line")
    declared = values.get("agents")
    if declared is not None:
        n = _positive_int(source, 1 + [k for k, _ in header].index("agents"), declared, "agents")
        if n != len(agents):
            raise MapFormatError(source, max(len(lines), 1),
                                 f"header says agents={n}, the file lists {len(agents)}")
    return AgentFile(source, tuple(agents), max(len(lines), 1), values["map_file"],
                     tuple(header))


def read_mapf_ir(path: str | Path) -> AgentFile:
    """Read a mapf-IR instance file."""
    p = Path(path)
    return parse_mapf_ir(p.read_text(encoding="utf-8"), source=str(p))
