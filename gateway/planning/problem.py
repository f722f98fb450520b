"""A checked planning problem in the planners' terms: states, goal cells, heuristics, windows."""

from __future__ import annotations

from collections.abc import Sequence

from gateway.planning.constraints import Constraint
from gateway.planning.grid import Cell, Grid
from gateway.planning.low_level import OmniModel
from gateway.planning.plan import NoSolution

Forbidden = tuple[Cell, int, int]
"""``(cell, t0, t1)``: no agent may be on the cell at any timestep in ``[t0, t1]``."""


class Problem:
    """Agents' start states, goal cell ids, exact heuristics and the forbidden windows.

    Raises ``ValueError`` on a malformed instance (cells not free, shared starts or goals, bad
    windows) and ``NoSolution`` when an agent cannot reach its goal at all.
    """

    def __init__(
        self,
        grid: Grid,
        starts: Sequence[Cell],
        goals: Sequence[Cell],
        forbidden: Sequence[Forbidden] = (),
    ) -> None:
        if len(starts) != len(goals):
            raise ValueError(f"{len(starts)} starts but {len(goals)} goals")
        self.start_cells: list[Cell] = [(int(x), int(y)) for x, y in starts]
        self.goal_cells: list[Cell] = [(int(x), int(y)) for x, y in goals]
        for what, cells in (("start", self.start_cells), ("goal", self.goal_cells)):
            for k, c in enumerate(cells):
                if not grid.is_free(c):
                    raise ValueError(f"{what} {c} of agent {k} is not a free cell of {grid!r}")
            if len(set(cells)) != len(cells):
                raise ValueError(f"two agents share a {what} cell")
        self.grid = grid
        self.model = OmniModel(grid)
        self.size = grid.size
        self.starts = [self.model.state(grid.index(c)) for c in self.start_cells]
        self.goals = [grid.index(c) for c in self.goal_cells]
        self.h = self.model.heuristics(self.goals)
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
