"""The solution JSON of DESIGN section 3 (``fleetgate plan --json``, the campaign's instance
files): one writer and one reader."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

from gateway.planning.grid import Cell
from gateway.planning.motion import HeadedCell
from gateway.planning.plan import Plan


@dataclass(frozen=True)
class SolutionJson:
    """An instance's starts and goals with its 1-robust plan and how it was found.

    Under ``turning`` (a plan with headings) starts and path entries are ``[x, y, heading]``.
    """

    map: str
    starts: tuple[Cell | HeadedCell, ...]
    goals: tuple[Cell, ...]
    plan: Plan
    optimal: bool
    runtime_s: float
    expanded_nodes: int

    def to_json(self) -> dict[str, Any]:
        """``{"map", "motion", "robust", "optimal", "soc", "makespan", "runtime_s",
        "expanded_nodes", "agents": [{"start", "goal", "path"}]}``."""
        return {
            "map": self.map,
            "motion": self.plan.motion,
            "robust": 1,
            "optimal": self.optimal,
            "soc": self.plan.soc,
            "makespan": self.plan.makespan,
            "runtime_s": round(self.runtime_s, 6),
            "expanded_nodes": self.expanded_nodes,
            "agents": [{"start": list(s), "goal": list(g), "path": path}
                       for s, g, path in zip(self.starts, self.goals, self.plan.json_paths(),
                                             strict=True)],
        }

    @staticmethod
    def from_json(data: dict[str, Any]) -> SolutionJson:
        """Inverse of :meth:`to_json` (KeyError/ValueError/TypeError on a malformed object)."""
        agents: Sequence[dict[str, Any]] = data["agents"]
        return SolutionJson(
            map=str(data["map"]),
            starts=tuple(_place(a["start"]) for a in agents),
            goals=tuple(_cell(a["goal"]) for a in agents),
            plan=Plan.from_json(data.get("motion", "omni"), [a["path"] for a in agents]),
            optimal=bool(data["optimal"]),
            runtime_s=float(data["runtime_s"]), expanded_nodes=int(data["expanded_nodes"]))


def _cell(value: Sequence[Any]) -> Cell:
    return int(value[0]), int(value[1])


def _place(value: Sequence[Any]) -> Cell | HeadedCell:
    """A start: ``[x, y]`` or ``[x, y, heading]``."""
    if len(value) == 3:
        return int(value[0]), int(value[1]), int(value[2])
    return _cell(value)
