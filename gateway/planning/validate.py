"""The independent plan checker: the oracle that every planner and test is held against.

Written straight from the definitions of DESIGN section 2, without any planner code:
a path starts at its agent's start and ends at its goal; each step is a wait or a move to a
4-neighbour, always on free cells; no two agents share a cell at any timestep (vertex
conflict); and the plan is 1-robust: for every t >= 1 and agents j != k,
``pos_k(t) != pos_j(t-1)`` (this forbids swap, following and cycle conflicts). After its path
ends an agent stays on its goal. A cycle conflict shows as a following conflict for each
agent of the cycle.

A ``turning`` plan (one with headings) is checked the same way on its cells, except that each
step must be a wait, a 90-degree turn in place, or one cell forward along the heading; a start
or goal given as ``(x, y, heading)`` fixes that heading too.
"""

from __future__ import annotations

from collections.abc import Sequence

from gateway.planning.grid import Cell, Grid
from gateway.planning.motion import HeadedCell, turning_step
from gateway.planning.plan import Plan


class InvalidPlan(ValueError):
    """A plan broke a rule; ``violations`` lists every problem found."""

    def __init__(self, violations: Sequence[str]) -> None:
        more = f" (and {len(violations) - 1} more)" if len(violations) > 1 else ""
        super().__init__(f"{violations[0]}{more}")
        self.violations = list(violations)


def _path_violations(grid: Grid, k: int, start: Cell, goal: Cell,
                     path: Sequence[Cell], steps: bool = True) -> list[str]:
    """Problems of one agent's cells taken alone (with ``steps``, the ``omni`` steps too)."""
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
    for t in range(1, len(path) if steps else 0):
        (x0, y0), (x1, y1) = path[t - 1], path[t]
        if abs(x1 - x0) + abs(y1 - y0) > 1:
            out.append(f"agent {k} t={t}: {path[t - 1]} -> {path[t]} is neither a wait nor a "
                       "move to a 4-neighbour")
    return out


def _turning_violations(k: int, start: Cell | HeadedCell, goal: Cell | HeadedCell,
                        poses: Sequence[HeadedCell]) -> list[str]:
    """Problems of one agent's headings and steps under the ``turning`` model (a non-empty
    path)."""
    out: list[str] = []
    for t, (_, _, h) in enumerate(poses):
        if h not in (0, 1, 2, 3):
            out.append(f"agent {k} t={t}: heading {h} is not 0-3")
    if out:
        return out
    if len(start) == 3 and poses[0][2] != start[2]:
        out.append(f"agent {k}: path starts with heading {poses[0][2]}, its start heading "
                   f"is {start[2]}")
    if len(goal) == 3 and poses[-1][2] != goal[2]:
        out.append(f"agent {k}: path ends with heading {poses[-1][2]}, its goal heading "
                   f"is {goal[2]}")
    for t in range(1, len(poses)):
        if not turning_step(poses[t - 1], poses[t]):
            out.append(f"agent {k} t={t}: {poses[t - 1]} -> {poses[t]} is not a wait, a "
                       "90-degree turn or one cell forward")
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


def plan_violations(grid: Grid, starts: Sequence[Cell | HeadedCell],
                    goals: Sequence[Cell | HeadedCell],
                    plan: Plan | Sequence[Sequence[Cell]]) -> list[str]:
    """Every way the plan breaks the rules (empty if it is a valid 1-robust plan).

    A ``turning`` plan's steps are checked under that model; ``(x, y, heading)`` starts and
    goals fix headings (of a ``turning`` plan; only the cells count for an ``omni`` plan).
    """
    if len(starts) != len(goals):
        raise ValueError(f"{len(starts)} starts but {len(goals)} goals")
    paths = [[(int(x), int(y)) for x, y in p]
             for p in (plan.paths if isinstance(plan, Plan) else plan)]
    if len(paths) != len(starts):
        return [f"the plan has {len(paths)} paths for {len(starts)} agents"]
    headings = plan.headings if isinstance(plan, Plan) else None
    out: list[str] = []
    for k, path in enumerate(paths):
        start, goal = starts[k], goals[k]
        cells = [(int(start[0]), int(start[1])), (int(goal[0]), int(goal[1]))]
        out.extend(_path_violations(grid, k, cells[0], cells[1], path, steps=headings is None))
        if headings is not None and path:
            poses = [(x, y, h) for (x, y), h in zip(path, headings[k], strict=True)]
            out.extend(_turning_violations(k, start, goal, poses))
    if all(paths):
        out.extend(_conflicts(paths))
    return out


def check_plan(grid: Grid, starts: Sequence[Cell | HeadedCell],
               goals: Sequence[Cell | HeadedCell],
               plan: Plan | Sequence[Sequence[Cell]]) -> None:
    """Raise :class:`InvalidPlan` unless the plan is a valid 1-robust plan for the instance."""
    violations = plan_violations(grid, starts, goals, plan)
    if violations:
        raise InvalidPlan(violations)
