"""The gateway's use of the planner: resolve instances by name and find 1-robust plans."""

from __future__ import annotations

import logging
import re
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from gateway.execution.errors import ExecutionError
from gateway.execution.oneshot.adg import ADG
from gateway.planning.generators import random_instance
from gateway.planning.grid import Cell, Grid
from gateway.planning.instance import Instance, load_instance, load_mapf_ir
from gateway.planning.motion import Motion
from gateway.planning.movingai import MapFormatError, read_map
from gateway.planning.plan import Plan
from gateway.planning.problem import Forbidden
from gateway.planning.solver import Place, solve
from gateway.planning.validate import plan_violations
from gateway.runtime import mapstore
from gateway.runtime.deadline import WallDeadline

log = logging.getLogger("fleetgate.planner")


class InstanceError(ValueError):
    """The named map, scenario or plan cannot be used; the message says why (``public``:
    the same without the server's file paths, for an operator's browser)."""

    def __init__(self, message: str, public: str | None = None) -> None:
        super().__init__(message)
        self.public = without_paths(public or message)


_PATH = re.compile(r"(?<![\w.~-])~?/(?:[^\s'\"/]+/)*")


def without_paths(text: str) -> str:
    """``text`` with the folders of every absolute path left out (``/srv/maps/x.map``:
    ``x.map``): a server's file layout is nobody's business in a browser."""
    return _PATH.sub("", text)


@dataclass(frozen=True)
class Problem:
    """What the gateway executes: an instance and, once planned, its plan."""

    instance: Instance
    map_name: str
    plan: Plan | None = None
    scen_name: str = ""
    """The scenario it was read from ("" for a generated instance or a given plan)."""


def _map(name: str) -> tuple[Grid, str]:
    path = mapstore.resolve(name, "map")
    return read_map(path), Path(path).stem


def resolve_instance(map: str, scen: str | None, agents: int | None, seed: int = 0,
                     instance_file: Path | None = None) -> Problem:
    """Load ``scen`` on ``map`` (first ``agents`` agents), a mapf-IR ``instance_file``, or
    ``agents`` random starts/goals drawn with ``seed``. Raises InstanceError."""
    try:
        if instance_file is not None:
            dirs = [d.path for d in mapstore.search_dirs()]
            inst = load_mapf_ir(instance_file, agents, mapstore.resolve(map, "map"), dirs)
            return Problem(inst, Path(instance_file).stem)
        grid, map_name = _map(map)
        if scen is not None:
            scen_path = mapstore.resolve(scen, "scen")
            inst = load_instance(mapstore.resolve(map, "map"), scen_path, agents)
            return Problem(inst, map_name, scen_name=Path(scen_path).stem)
        if agents is None:
            raise InstanceError("give a scenario or a number of agents to generate")
        inst = random_instance(grid, agents, np.random.default_rng(seed), name=map_name)
        return Problem(inst, map_name)
    except mapstore.MapNotFound as exc:
        raise InstanceError(str(exc), exc.public) from None
    except (MapFormatError, ValueError) as exc:
        raise InstanceError(str(exc)) from None
    except OSError as exc:
        raise InstanceError(f"cannot read {exc.filename}: {exc.strerror}") from None


def problem_from_paths(map: str, paths: list[list[Cell]],
                       headings: list[list[int]] | None = None) -> Problem:
    """A given plan on a named map (``turning`` with ``headings``), checked to be a valid
    1-robust plan of legal actions. Raises InstanceError."""
    try:
        grid, map_name = _map(map)
    except mapstore.MapNotFound as exc:
        raise InstanceError(str(exc), exc.public) from None
    except (MapFormatError, OSError) as exc:
        raise InstanceError(f"cannot read map {map!r}: {exc}") from None
    if headings is None:
        plan = Plan.of(paths)
    else:
        if [len(h) for h in headings] != [len(p) for p in paths]:
            raise InstanceError("a turning plan needs one heading per cell of every path")
        plan = Plan(tuple(tuple((int(x), int(y)) for x, y in p) for p in paths),
                    tuple(tuple(int(h) for h in hs) for hs in headings))
        try:
            ADG(plan)  # every step a legal action of the turning model
        except ExecutionError as exc:
            raise InstanceError(f"invalid plan: {exc}") from None
    starts = tuple(p[0] for p in plan.paths)
    goals = tuple(p[-1] for p in plan.paths)
    problems = plan_violations(grid, starts, goals, plan)
    if problems:
        more = f" (+{len(problems) - 1} more)" if len(problems) > 1 else ""
        raise InstanceError(f"invalid plan: {problems[0]}{more}")
    return Problem(Instance(grid, starts, goals, map_name), map_name, plan)


def plan_for(grid: Grid, starts: Sequence[Place], goals: tuple[Cell, ...],
             time_limit_s: float, fallback_s: float | None = None,
             motion: Motion = "omni", forbidden: Sequence[Forbidden] = ()) -> Plan:
    """A 1-robust plan from ``starts`` (``(x, y, heading)`` under ``turning``) to ``goals``
    (raises planning's NoSolution), keeping off the ``forbidden`` cells: CBS's within
    ``time_limit_s``, else (given ``fallback_s``) the prioritised planner's, with a
    warning."""
    fallback = WallDeadline(time_limit_s + fallback_s) if fallback_s else None
    solution = solve(grid, starts, goals, deadline=WallDeadline(time_limit_s), fallback=fallback,
                     motion=motion, forbidden=forbidden)
    if not solution.optimal:
        log.warning("no optimal plan within %g s: using the prioritised planner's plan "
                    "(SOC %d, not proven optimal)", time_limit_s, solution.plan.soc)
    return solution.plan
