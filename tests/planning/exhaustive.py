"""An independent, obviously-correct optimum: A* over joint states of all agents.

A joint state is (every agent's cell, which agents have "finished", time capped after the last
forbidden window). A finished agent stands on its goal for ever; finishing is free and allowed
only on the goal. Each joint step costs the number of unfinished agents, so a run's cost is the
sum over agents of the time they finished, which is exactly the SOC of DESIGN section 2 (an
agent may cross its goal earlier and leave: only the final arrival counts). A step is allowed
when no two agents share a cell after it, no agent enters a cell another agent held before it
(the 1-robust rule), and no agent is on a forbidden cell.

Under the ``turning`` model an agent's state is ``(x, y, heading)`` and a step is a wait, a
quarter turn either way or one cell forward along the heading (written out here again, from
DESIGN section 2, not taken from the planner); the rules above stay on cells, and an agent may
finish only on its goal cell (with its goal heading, if the goal gives one).

The A* heuristic is the sum over unfinished agents of each one's distance to its goal alone
(ignoring the others and the windows), computed here by plain fixpoint iteration. It is
admissible and consistent (a joint step costs one per unfinished agent and lowers each such
distance by at most one; finishing needs distance 0), so the first goal state taken from the
queue is optimal, exactly as with Dijkstra (h = 0), only faster.
"""

from __future__ import annotations

import heapq
import itertools
from collections.abc import Sequence

from gateway.planning.grid import Cell, Grid

Forbidden = tuple[Cell, int, int]


AgentState = tuple[int, ...]
"""``(x, y)`` under ``omni``, ``(x, y, heading)`` under ``turning``."""

JointState = tuple[tuple[AgentState, ...], frozenset[int], int]
"""Every agent's state, the agents that have finished, and the (capped) time."""

FORWARD = {0: (1, 0), 1: (0, 1), 2: (-1, 0), 3: (0, -1)}
"""Heading -> the cell step of moving forward: east, south, west, north."""


def _successors(grid: Grid, state: AgentState) -> list[AgentState]:
    """The states one timestep after ``state`` (waiting included)."""
    if len(state) == 2:
        x, y = state
        return [(x, y), *grid.neighbours((x, y))]
    x, y, h = state
    out: list[AgentState] = [(x, y, h), (x, y, (h + 1) % 4), (x, y, (h - 1) % 4)]
    dx, dy = FORWARD[h]
    if grid.is_free((x + dx, y + dy)):
        out.append((x + dx, y + dy, h))
    return out


def optimal_soc(
    grid: Grid,
    starts: Sequence[AgentState],
    goals: Sequence[AgentState],
    forbidden: Sequence[Forbidden] = (),
    max_cost: int = 60,
) -> int | None:
    """The minimum sum of costs of a 1-robust plan, or None if there is none below max_cost.

    ``omni`` with ``(x, y)`` starts; ``turning`` with ``(x, y, heading)`` starts (goals
    ``(x, y)``, or ``(x, y, heading)`` to fix the final heading).
    """
    n = len(starts)
    t_cap = max((t1 for _, _, t1 in forbidden), default=-1) + 1

    def blocked(cell: Cell, t: int) -> bool:
        return any(c == cell and t0 <= t <= t1 for c, t0, t1 in forbidden)

    def cell(state: AgentState) -> Cell:
        return (state[0], state[1])

    def at_goal(k: int, state: AgentState) -> bool:
        return state[: len(goals[k])] == tuple(goals[k])

    if any(blocked(cell(s), 0) for s in starts):
        return None
    goal_cells = [cell(g) for g in goals]
    singles: list[AgentState] = [(x, y) for x, y in grid.free_cells()]
    if starts and len(starts[0]) == 3:
        singles = [(x, y, h) for x, y in singles for h in range(4)]
    succ = {s: _successors(grid, s) for s in singles}
    inf = max_cost + 1
    dist: list[dict[AgentState, int]] = []
    for k in range(n):
        d = {s: 0 if at_goal(k, s) else inf for s in singles}
        changed = True
        while changed:
            changed = False
            for s in singles:
                best_next = min(d[u] for u in succ[s]) + 1
                if best_next < d[s]:
                    d[s] = best_next
                    changed = True
        dist.append(d)

    def h(states: tuple[AgentState, ...], done: frozenset[int]) -> int:
        return sum(dist[k][states[k]] for k in range(n) if k not in done)

    def successors(state: AgentState) -> list[AgentState]:
        return succ[state]

    start = (tuple(tuple(s) for s in starts), frozenset[int](), 0)
    best = {start: 0}
    heap: list[tuple[int, int, int, JointState]] = [(h(start[0], start[1]), 0, 0, start)]
    counter = itertools.count(1)

    def push(cost: int, nxt: JointState) -> None:
        f = cost + h(nxt[0], nxt[1])
        if f <= max_cost and cost < best.get(nxt, inf):
            best[nxt] = cost
            heapq.heappush(heap, (f, next(counter), cost, nxt))

    while heap:
        _, _, cost, state = heapq.heappop(heap)
        if cost > best.get(state, inf):
            continue
        states, done, t = state
        if len(done) == n and not any(c in goal_cells and t1 > t for c, _, t1 in forbidden):
            return cost  # everyone parked for good and no later window hits a parked agent
        # finishing: any unfinished agent on its goal may finish now, for free
        for k in range(n):
            if k not in done and at_goal(k, states[k]):
                push(cost, (states, done | {k}, t))
        step = cost + n - len(done)
        nt = t + 1
        options = [[states[k]] if k in done else successors(states[k]) for k in range(n)]
        cells = [cell(s) for s in states]
        for new in itertools.product(*options):
            new_cells = [cell(s) for s in new]
            if len(set(new_cells)) < n:
                continue
            if any(new_cells[k] == cells[j] for k in range(n) for j in range(n) if j != k):
                continue
            if any(blocked(c, nt) for c in new_cells):
                continue
            push(step, (tuple(new), done, min(nt, t_cap)))
    return None
