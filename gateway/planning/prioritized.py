"""Prioritised planning under the 1-robust rule: fast, complete only in practice, suboptimal.

Agents are planned one at a time in priority order by space-time A* against a reservation table
of the agents before them: a planned agent on cell v at t reserves v at t-1, t and t+1 (the
1-robust rule), and from the step before it reaches its goal it holds the goal for ever. Every
agent not yet planned holds its start at t = 1, since nobody may enter a cell that an agent
occupied the step before (they hold it a little longer, see ``START_HOLD``). Agents whose goal
is cut off from their start by the other agents' goals go first, since those goals get parked
on. When an agent finds no path (or none within an expansion budget), the
search restarts with that agent moved to the front; an agent that fails again while already in
front gets the others shuffled behind it (seeded, so runs are reproducible).
"""

from __future__ import annotations

import random
from collections.abc import Sequence

from gateway.planning.connectivity import component_labels
from gateway.planning.constraints import INF, ConstraintTable
from gateway.planning.grid import Grid
from gateway.planning.low_level import space_time_astar
from gateway.planning.motion import Motion
from gateway.planning.plan import Deadline, NoSolution, Solution
from gateway.planning.problem import Forbidden, Place, Problem

EXPANSION_BUDGET = 300
"""An agent's search gives up after this many expansions per timestep of its horizon."""

START_HOLD = 3
"""Agents not yet planned hold their starts during timesteps 1..START_HOLD, so that each can
still wait there for START_HOLD - 1 steps when its turn comes."""


class _Reservations:
    """The reservation table of one attempt, viewed by the low level as a ConstraintTable."""

    def __init__(self, problem: Problem) -> None:
        size = problem.size
        self.size = size
        self.counts: dict[int, int] = {}
        self.permanent: dict[int, int] = {}
        self.last: dict[int, int] = {}
        self.horizon = 1
        for cell, t0, t1 in problem.base:
            for t in range(t0, t1 + 1):
                self._add(t, cell)
        for s in problem.starts:
            for t in range(1, START_HOLD + 1):
                self._add(t, problem.model.cells[s])

    def _add(self, t: int, cell: int) -> None:
        key = t * self.size + cell
        self.counts[key] = self.counts.get(key, 0) + 1
        if t > self.last.get(cell, -1):
            self.last[cell] = t
        if t >= self.horizon:
            self.horizon = t + 1

    def release(self, t: int, cell: int) -> None:
        """Undo one :meth:`_add` (an agent's own start hold, before it is planned)."""
        key = t * self.size + cell
        left = self.counts[key] - 1
        if left:
            self.counts[key] = left
        else:
            del self.counts[key]

    def reserve(self, path: Sequence[int]) -> None:
        """Reserve a planned agent's cells (with the 1-robust margin) and its goal for ever."""
        end = len(path) - 1
        for t in range(end):
            v = path[t]
            for tt in (t - 1, t, t + 1):
                if tt >= 0:
                    self._add(tt, v)
        goal = path[end]
        since = max(end - 1, 0)
        if since < self.permanent.get(goal, INF):
            self.permanent[goal] = since
        self.horizon = max(self.horizon, end + 1)

    def table(self) -> ConstraintTable:
        """The current reservations as constraints."""
        return ConstraintTable(self.size, self.counts, self.permanent, self.last, self.horizon)


def _attempt(
    problem: Problem, order: Sequence[int], deadline: Deadline
) -> list[list[int]] | int:
    """Plan agents in ``order``; the paths of states (indexed by agent) or the agent that
    failed."""
    res = _Reservations(problem)
    paths: list[list[int]] = [[] for _ in range(problem.num_agents)]
    for k in order:
        start_cell = problem.model.cells[problem.starts[k]]
        for t in range(1, START_HOLD + 1):
            res.release(t, start_cell)
        budget = EXPANSION_BUDGET * (problem.h[k][problem.starts[k]] + res.horizon + 1)
        states = space_time_astar(
            problem.model, problem.starts[k], problem.goals[k], problem.h[k], res.table(), None,
            deadline, budget,
        )
        if states is None:
            return k
        paths[k] = states
        res.reserve(problem.cells_of(states))
    return paths


def _boxed_in(problem: Problem) -> set[int]:
    """Agents whose goal cannot be reached from their start once all other goals are taken."""
    free = problem.grid.free.copy()
    for g in problem.goals:
        free.flat[g] = False
    if not free.any():
        return set(range(problem.num_agents))
    labels = component_labels(Grid(free)).ravel().tolist()
    out = set()
    nbrs = problem.grid.neighbour_ids
    for k, (s, g) in enumerate(zip(problem.starts, problem.goals, strict=True)):
        s_cell = problem.model.cells[s]
        from_start = {labels[c] for c in (s_cell, *nbrs(s_cell))} - {0}
        to_goal = {labels[c] for c in nbrs(g)} - {0}
        if s_cell != g and not from_start & to_goal and g not in nbrs(s_cell):
            out.add(k)
    return out


def solve_prioritized(
    grid: Grid,
    starts: Sequence[Place],
    goals: Sequence[Place],
    *,
    deadline: Deadline,
    forbidden: Sequence[Forbidden] = (),
    attempts: int = 20,
    seed: int = 0,
    motion: Motion = "omni",
) -> Solution:
    """A valid 1-robust plan by prioritised planning (``optimal=False``; ``expanded_nodes`` is
    the number of orders tried).

    The first order plans the agents with the longest distance first; agents that fail move to
    the front. Raises ``NoSolution``
    after ``attempts`` failed orders (``timed_out=True`` if the deadline expired first) and
    ``ValueError`` on a malformed instance.
    """
    problem = Problem(grid, starts, goals, forbidden, motion)
    rng = random.Random(seed)
    boxed = _boxed_in(problem)
    order = sorted(range(problem.num_agents),
                   key=lambda k: (k not in boxed, -problem.h[k][problem.starts[k]]))
    front: list[int] = []
    for attempt in range(1, attempts + 1):
        if deadline.expired():
            raise NoSolution("deadline expired in prioritised planning", timed_out=True)
        got = _attempt(problem, order, deadline)
        if isinstance(got, list):
            return Solution(problem.plan_of(got), optimal=False, expanded_nodes=attempt)
        if got in front:
            front.remove(got)
            rest = [k for k in order if k not in front and k != got]
            rng.shuffle(rest)
        else:
            rest = [k for k in order if k not in front and k != got]
        front.insert(0, got)
        order = [*front, *rest]
    raise NoSolution(f"prioritised planning found no plan in {attempts} orders")
