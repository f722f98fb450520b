"""An independent, obviously-correct optimum: Dijkstra over joint states of all agents.

A joint state is (every agent's cell, which agents have "finished", time capped after the last
forbidden window). A finished agent stands on its goal for ever; finishing is free and allowed
only on the goal. Each joint step costs the number of unfinished agents, so a run's cost is the
sum over agents of the time they finished, which is exactly the SOC of DESIGN section 2 (an
agent may cross its goal earlier and leave: only the final arrival counts). A step is allowed
when no two agents share a cell after it, no agent enters a cell another agent held before it
(the 1-robust rule), and no agent is on a forbidden cell.
"""

from __future__ import annotations

import heapq
import itertools
from collections.abc import Sequence

from gateway.planning.grid import Cell, Grid

Forbidden = tuple[Cell, int, int]


def optimal_soc(
    grid: Grid,
    starts: Sequence[Cell],
    goals: Sequence[Cell],
    forbidden: Sequence[Forbidden] = (),
    max_cost: int = 60,
) -> int | None:
    """The minimum sum of costs of a 1-robust plan, or None if there is none below max_cost."""
    n = len(starts)
    t_cap = max((t1 for _, _, t1 in forbidden), default=-1) + 1

    def blocked(cell: Cell, t: int) -> bool:
        return any(c == cell and t0 <= t <= t1 for c, t0, t1 in forbidden)

    if any(blocked(s, 0) for s in starts):
        return None
    moves = [[c, *grid.neighbours(c)] for c in (grid.cell(i) for i in range(grid.size))]
    goals = [(g[0], g[1]) for g in goals]
    start = (tuple(starts), frozenset[int](), 0)
    best = {start: 0}
    heap: list[tuple[int, int, tuple[tuple[Cell, ...], frozenset[int], int]]] = [(0, 0, start)]
    counter = itertools.count(1)
    while heap:
        cost, _, state = heapq.heappop(heap)
        if cost > best.get(state, max_cost + 1) or cost > max_cost:
            continue
        cells, done, t = state
        if len(done) == n and not any(c in goals and t1 > t for c, _, t1 in forbidden):
            return cost  # everyone parked for good and no later window hits a parked agent
        # finishing: any unfinished agent on its goal may finish now, for free
        for k in range(n):
            if k not in done and cells[k] == goals[k]:
                nxt = (cells, done | {k}, t)
                if cost < best.get(nxt, max_cost + 1):
                    best[nxt] = cost
                    heapq.heappush(heap, (cost, next(counter), nxt))
        step = cost + n - len(done)
        nt = t + 1
        options = [
            [cells[k]] if k in done else moves[grid.index(cells[k])] for k in range(n)
        ]
        for new in itertools.product(*options):
            if len(set(new)) < n:
                continue
            if any(new[k] == cells[j] for k in range(n) for j in range(n) if j != k):
                continue
            if any(blocked(c, nt) for c in new):
                continue
            nxt = (tuple(new), done, min(nt, t_cap))
            if step < best.get(nxt, max_cost + 1):
                best[nxt] = step
                heapq.heappush(heap, (step, next(counter), nxt))
    return None
