"""A checked planning problem in the planners' terms: states, goal cells, heuristics, windows."""

from __future__ import annotations

from collections.abc import Sequence

from gateway.planning.constraints import Constraint
from gateway.planning.grid import Cell, Grid
from gateway.planning.low_level import motion_model
from gateway.planning.motion import HeadedCell, Motion
from gateway.planning.plan import NoSolution, Plan

Forbidden = tuple[Cell, int, int]
"""``(cell, t0, t1)``: no agent may be on the cell at any timestep in ``[t0, t1]``."""

Place = Cell | HeadedCell
"""A start or goal: ``(x, y)``, or ``(x, y, heading)`` under the ``turning`` model."""


def _headings(places: Sequence[Place], what: str, motion: Motion,
              required: bool) -> list[int | None]:
    """The heading of each place (None where it has none); ``ValueError`` if malformed."""
    out: list[int | None] = []
    for k, place in enumerate(places):
        if len(place) == 3 and motion == "turning":
            h = int(place[2])
            if not 0 <= h <= 3:
                raise ValueError(f"{what} heading {h} of agent {k} is not 0-3")
            out.append(h)
        elif len(place) == 2 and not (required and motion == "turning"):
            out.append(None)
        else:
            shape = "(x, y, heading)" if motion == "turning" else "(x, y)"
            raise ValueError(f"{what} {tuple(place)} of agent {k}: give {shape} under the "
                             f"{motion} model")
    return out


class Problem:
    """Agents' start states, goal cell ids, exact heuristics and the forbidden windows.

    Under ``omni`` starts and goals are ``(x, y)``; under ``turning`` starts are
    ``(x, y, heading)`` and goals ``(x, y)`` (any final heading) or ``(x, y, heading)``.
    Raises ``ValueError`` on a malformed instance (cells not free, shared starts or goals, bad
    windows or headings) and ``NoSolution`` when an agent cannot reach its goal at all.
    """

    def __init__(
        self,
        grid: Grid,
        starts: Sequence[Place],
        goals: Sequence[Place],
        forbidden: Sequence[Forbidden] = (),
        motion: Motion = "omni",
    ) -> None:
        if len(starts) != len(goals):
            raise ValueError(f"{len(starts)} starts but {len(goals)} goals")
        self.motion: Motion = motion
        self.model = motion_model(grid, motion)
        start_headings = _headings(starts, "start", motion, required=True)
        self.goal_headings = _headings(goals, "goal", motion, required=False)
        self.start_cells: list[Cell] = [(int(p[0]), int(p[1])) for p in starts]
        self.goal_cells: list[Cell] = [(int(p[0]), int(p[1])) for p in goals]
        for what, cells in (("start", self.start_cells), ("goal", self.goal_cells)):
            for k, c in enumerate(cells):
                if not grid.is_free(c):
                    raise ValueError(f"{what} {c} of agent {k} is not a free cell of {grid!r}")
            if len(set(cells)) != len(cells):
                raise ValueError(f"two agents share a {what} cell")
        self.grid = grid
        self.size = grid.size
        self.starts = [self.model.state(grid.index(c), h or 0)
                       for c, h in zip(self.start_cells, start_headings, strict=True)]
        self.goals = [grid.index(c) for c in self.goal_cells]
        self.h = self.model.heuristics(self.goals, self.goal_headings)
        for k, (s, hk) in enumerate(zip(self.starts, self.h, strict=True)):
            if hk[s] < 0:
                raise NoSolution(
                    f"agent {k} cannot reach its goal {goals[k]} from {starts[k]}"
                )
        self.base: list[Constraint] = []
        for cell, t0, t1 in forbidden:
            if not grid.is_free(cell):
                raise ValueError(f"forbidden cell {cell} is not a free cell of {grid!r}")
            if not 0 <= t0 <= t1:
                raise ValueError(f"bad forbidden window [{t0}, {t1}] on {cell}")
            self.base.append((grid.index(cell), int(t0), int(t1)))

    @property
    def num_agents(self) -> int:
        """Number of agents."""
        return len(self.starts)

    def cells_of(self, states: Sequence[int]) -> tuple[int, ...]:
        """The cell ids of a path of states."""
        cells = self.model.cells
        return tuple(cells[s] for s in states)

    def plan_of(self, state_paths: Sequence[Sequence[int]]) -> Plan:
        """The plan of one path of states per agent (with headings under ``turning``)."""
        cell = self.grid.cell
        cells = self.model.cells
        if self.motion == "omni":
            return Plan.of([[cell(cells[s]) for s in p] for p in state_paths])
        heading = self.model.heading
        return Plan.of_poses([[(*cell(cells[s]), heading(s)) for s in p] for p in state_paths])
