"""MAPF instances: a grid plus one start and one goal per agent, loaded and checked from files."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from gateway.planning.connectivity import component_labels
from gateway.planning.grid import Cell, Grid
from gateway.planning.motion import DEFAULT_START_HEADING, HeadedCell
from gateway.planning.movingai import (
    AgentFile,
    MapFormatError,
    ScenEntry,
    read_map,
    read_mapf_ir,
    read_scen,
)


@dataclass(frozen=True)
class Instance:
    """A MAPF instance: agent k goes from ``starts[k]`` to ``goals[k]`` on ``grid``.

    ``start_headings`` are the agents' headings for the ``turning`` model, if the instance
    gives them (MovingAI scenarios, mapf-IR and LoRR agent files do not).
    """

    grid: Grid
    starts: tuple[Cell, ...]
    goals: tuple[Cell, ...]
    name: str = ""
    start_headings: tuple[int, ...] | None = None

    def __post_init__(self) -> None:
        if len(self.starts) != len(self.goals):
            raise ValueError(f"{len(self.starts)} starts but {len(self.goals)} goals")
        if self.start_headings is not None:
            if len(self.start_headings) != len(self.starts):
                raise ValueError(f"{len(self.starts)} starts but {len(self.start_headings)} "
                                 "start headings")
            if not all(h in (0, 1, 2, 3) for h in self.start_headings):
                raise ValueError("start headings must be 0-3")

    def turning_starts(self, default: int = DEFAULT_START_HEADING) -> tuple[HeadedCell, ...]:
        """Starts as ``(x, y, heading)``: the instance's headings, else ``default`` for all."""
        headings = self.start_headings or (default,) * len(self.starts)
        return tuple((x, y, h) for (x, y), h in zip(self.starts, headings, strict=True))

    @property
    def num_agents(self) -> int:
        """Number of agents."""
        return len(self.starts)


def _cell_problem(grid: Grid, cell: Cell) -> str | None:
    if not grid.in_bounds(cell):
        return f"is outside the {grid.width}x{grid.height} map"
    if not grid.is_free(cell):
        return "is on an obstacle"
    return None


def instance_from_agents(grid: Grid, agents: AgentFile, count: int | None = None,
                         name: str = "") -> Instance:
    """The instance of the first ``count`` agents of a file (all if None), checked on ``grid``.

    Raises :class:`MapFormatError` (``file:line: reason``) when a scenario line is for a map of
    another size, a start or goal is outside the map or on an obstacle, two agents share a start
    or a goal, a goal is not reachable from its start, or more agents are asked than listed.
    """
    if count is not None and count < 1:
        raise ValueError(f"the number of agents must be at least 1, got {count}")
    listed = agents.agents
    if count is not None and count > len(listed):
        raise MapFormatError(agents.source, agents.last_line,
                             f"{count} agents asked, the file lists only {len(listed)}")
    chosen = listed if count is None else listed[:count]
    labels = component_labels(grid)
    start_lines: dict[Cell, int] = {}
    goal_lines: dict[Cell, int] = {}
    for spec in chosen:
        where = (agents.source, spec.line)
        if isinstance(spec, ScenEntry) and spec.width and (spec.width, spec.height) != (
                grid.width, grid.height):
            raise MapFormatError(*where, f"scenario is for a {spec.width}x{spec.height} map, "
                                 f"the map is {grid.width}x{grid.height}")
        for role, cell, seen in (("start", spec.start, start_lines),
                                 ("goal", spec.goal, goal_lines)):
            problem = _cell_problem(grid, cell)
            if problem:
                raise MapFormatError(*where, f"{role} {cell} {problem}")
            if cell in seen:
                raise MapFormatError(*where, f"{role} {cell} is also the {role} of the agent "
                                     f"on line {seen[cell]}")
            seen[cell] = spec.line
        (sx, sy), (gx, gy) = spec.start, spec.goal
        if labels[sy, sx] != labels[gy, gx]:
            raise MapFormatError(*where, f"goal {spec.goal} is not reachable from start "
                                 f"{spec.start}")
    return Instance(grid, tuple(s.start for s in chosen), tuple(s.goal for s in chosen), name)


def load_instance(map: str | Path, scen: str | Path, agents: int | None = None) -> Instance:
    """Load the first ``agents`` agents (all if None) of a ``.scen`` file on a ``.map`` file."""
    grid = read_map(map)
    return instance_from_agents(grid, read_scen(scen), agents, name=Path(scen).stem)


def mapf_ir_map_candidates(path: str | Path, map_file: str,
                           search_dirs: Sequence[Path] = ()) -> list[Path]:
    """Where the map a mapf-IR file names is looked for, in order.

    Next to the instance file, in its parent folder and the parent's ``map/`` folder (the
    layout of the mapf-IR repository and of ``shared/maps``), then in ``search_dirs``.
    """
    here = Path(path).parent
    return [here / map_file, here.parent / map_file, here.parent / "map" / map_file,
            *(Path(d) / map_file for d in search_dirs)]


def load_mapf_ir(path: str | Path, agents: int | None = None, map_path: str | Path | None = None,
                 search_dirs: Sequence[Path] = ()) -> Instance:
    """Load the first ``agents`` agents (all if None) of a mapf-IR instance file.

    The map is ``map_path`` if given, else the first of :func:`mapf_ir_map_candidates` that
    exists.
    """
    parsed = read_mapf_ir(path)
    if map_path is None:
        candidates = mapf_ir_map_candidates(path, parsed.map_file, search_dirs)
        found = next((c for c in candidates if c.is_file()), None)
        if found is None:
            raise MapFormatError(parsed.source, 1, f"map_file {parsed.map_file!r} not found "
                                 f"(looked in {', '.join(str(c.parent) for c in candidates)})")
        map_path = found
    grid = read_map(map_path)
    return instance_from_agents(grid, parsed, agents, name=Path(path).stem)
