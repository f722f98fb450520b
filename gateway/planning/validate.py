"""The independent plan checker: the oracle that every planner and test is held against.

Written straight from the definitions of DESIGN section 2, without any planner code:
a path starts at its agent's start and ends at its goal; each step is a wait or a move to a
4-neighbour, always on free cells; no two agents share a cell at any timestep (vertex
conflict); and the plan is 1-robust: for every t >= 1 and agents j != k,
``pos_k(t) != pos_j(t-1)`` (this forbids swap, following and cycle conflicts). After its path
ends an agent stays on its goal. A cycle conflict shows as a following conflict for each
agent of the cycle.
"""

from __future__ import annotations

from collections.abc import Sequence

from gateway.planning.grid import Cell, Grid
from gateway.planning.plan import Plan


class InvalidPlan(ValueError):
    """A plan broke a rule; ``violations`` lists every problem found."""

    def __init__(self, violations: Sequence[str]) -> None:
        more = f" (and {len(violations) - 1} more)" if len(violations) > 1 else ""
        super().__init__(f"{violations[0]}{more}")
        self.violations = list(violations)


def _path_violations(grid: Grid, k: int, start: Cell, goal: Cell,
                     path: Sequence[Cell]) -> list[str]:
    """Problems of one agent's path taken alone."""
    if not path:
        return [f"agent {k}: empty path"]
    out: list[str] = []
    if path[0] != start:
        out.append(f"agent {k}: path starts at {path[0]}, its start is {start}")
    if path[-1] != goal:
        out.append(f"agent {k}: path ends at {path[-1]}, its goal is {goal}")
    for t, cell in enumerate(path):
        if not grid.is_free(cell):
            out.append(f"agent {k} t={t}: {cell} is not a free cell")
    for t in range(1, len(path)):
        (x0, y0), (x1, y1) = path[t - 1], path[t]
        if abs(x1 - x0) + abs(y1 - y0) > 1:
            out.append(f"agent {k} t={t}: {path[t - 1]} -> {path[t]} is neither a wait nor a "
                       "move to a 4-neighbour")
    return out


def _position(path: Sequence[Cell], t: int) -> Cell:
    return path[t] if t < len(path) else path[-1]


def _conflicts(paths: Sequence[Sequence[Cell]]) -> list[str]:
    """Vertex conflicts and 1-robustness violations between agents (all paths non-empty)."""
    out: list[str] = []
    horizon = max(len(p) for p in paths)
    previous: dict[Cell, int] = {}
    for t in range(horizon):
        now: dict[Cell, int] = {}
        for k, path in enumerate(paths):
            cell = _position(path, t)
            if cell in now:
                out.append(f"vertex conflict: agents {now[cell]} and {k} at {cell} at t={t}")
            else:
                now[cell] = k
            j = previous.get(cell, k)
            if j != k and _position(paths[j], t) != cell:  # else: a vertex conflict at t
                kind = "swap" if _position(paths[j], t) == _position(path, t - 1) else "following"
                out.append(f"{kind} conflict (not 1-robust): agent {k} is at {cell} at t={t}, "
                           f"where agent {j} was at t={t - 1}")
        previous = now
    return out


def plan_violations(grid: Grid, starts: Sequence[Cell], goals: Sequence[Cell],
                    plan: Plan | Sequence[Sequence[Cell]]) -> list[str]:
    """Every way the plan breaks the rules (empty if it is a valid 1-robust plan)."""
    if len(starts) != len(goals):
        raise ValueError(f"{len(starts)} starts but {len(goals)} goals")
    paths = [[(int(x), int(y)) for x, y in p]
             for p in (plan.paths if isinstance(plan, Plan) else plan)]
    if len(paths) != len(starts):
        return [f"the plan has {len(paths)} paths for {len(starts)} agents"]
    out: list[str] = []
    for k, path in enumerate(paths):
        out.extend(_path_violations(grid, k, starts[k], goals[k], path))
    if all(paths):
        out.extend(_conflicts(paths))
    return out


def check_plan(grid: Grid, starts: Sequence[Cell], goals: Sequence[Cell],
               plan: Plan | Sequence[Sequence[Cell]]) -> None:
    """Raise :class:`InvalidPlan` unless the plan is a valid 1-robust plan for the instance."""
    violations = plan_violations(grid, starts, goals, plan)
    if violations:
        raise InvalidPlan(violations)
