"""A windowed, 1-robust PIBT planner for lifelong operation (pure, scales to thousands).

Each call plans ``steps`` timesteps ahead for the whole fleet, one timestep at a time, in the
manner of PIBT (Okumura et al., AIJ 2022): robots decide in priority order (time since their
last goal, then a random tie-break), each takes its best successor state by the exact distance
to its goal, and a robot that wants a cell held by a robot that has not decided yet asks that
robot to move away first (priority inheritance). The difference from PIBT is the 1-robust rule
(DESIGN section 2): a robot never enters a cell that another robot held at the previous
timestep, so an asked robot clears the cell during this timestep and the asker enters at the
next. ``omni`` (states are cells) and ``turning`` (states are ``cell * 4 + heading``, actions
forward, clockwise, counter-clockwise, wait) are both supported.

Guarantees: every returned step is free of vertex conflicts and 1-robust (waiting in place is
always possible, and nobody else may enter a held cell), so :class:`~gateway.execution.
live_adg.LiveADG` accepts it and its execution is collision-free under any delays. Each
timestep costs O(robots x actions) plus the pushes. Like PIBT it is not complete: in rare
cyclic jams robots may wait until priorities rotate. Distances are the exact tables of
:mod:`gateway.planning.distance` (cells, or ``turning`` states), one per goal cell, cached
within a memory budget.
"""

from __future__ import annotations

import random
from array import array
from collections import OrderedDict
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from gateway.planning.distance import distance_tables, turning_distance_tables
from gateway.planning.grid import Grid

UNREACHABLE = 32000
"""Distance of a state that cannot reach the goal (tables are int16)."""
MAX_PUSH_DEPTH = 64
"""Longest chain of robots asked to move away within one timestep."""


class StateSpace:
    """The planner's state graph on a grid: successors per state, and distance tables.

    ``omni``: state = cell id, successors = free 4-neighbours and the cell itself (wait).
    ``turning``: state = ``cell * 4 + heading``; successors = forward (if free), clockwise,
    counter-clockwise, wait. ``cell_of[s]`` is the cell a state stands on.
    """

    def __init__(self, grid: Grid, turning: bool, budget_bytes: int = 512 << 20) -> None:
        self.grid = grid
        self.turning = turning
        n, w = grid.size, grid.width
        free = grid.free.ravel()
        # options[s]: (cell, evaluated state, turns, resulting state) per neighbour cell and
        # the own cell (a wait): under turning a robot that does not face the chosen cell
        # turns towards it this timestep (and stays), as the evaluated state says
        options: list[tuple[tuple[int, int, int, int], ...]] = []
        if turning:
            ns = 4 * n
            self.cell_of: list[int] = [s >> 2 for s in range(ns)]
            deltas = (1, w, -1, -w)
            for c in range(n):
                x = c % w
                dirs = {}
                for d, delta in enumerate(deltas):
                    nxt = c + delta
                    if (0 <= nxt < n and free[nxt]
                            and not (d == 0 and x == w - 1) and not (d == 2 and x == 0)):
                        dirs[d] = nxt
                for h in range(4):
                    s = 4 * c + h
                    if not free[c]:
                        options.append(())
                        continue
                    opts = [(c, s, 0, s)]
                    for d, nxt in dirs.items():
                        turns = (d - h) % 4
                        if turns == 0:
                            opts.append((nxt, 4 * nxt + d, 0, 4 * nxt + h))
                        else:
                            step = 1 if turns in (1, 2) else 3
                            opts.append((nxt, 4 * nxt + d, min(turns, 4 - turns),
                                         4 * c + (h + step) % 4))
                    options.append(tuple(opts))
        else:
            ns = n
            self.cell_of = list(range(n))
            for c in range(n):
                nb = grid.neighbour_ids(c)
                options.append(((c, c, 0, c), *((v, v, 0, v) for v in nb)) if free[c] else ())
        self.n_states = ns
        self.options = options
        self._cache: OrderedDict[int, array[int]] = OrderedDict()
        self._capacity = max(16, budget_bytes // (2 * ns))

    def state(self, cell: int, heading: int = 0) -> int:
        """The state of a robot on ``cell`` (facing ``heading`` under ``turning``)."""
        return 4 * cell + heading if self.turning else cell

    def heading_of(self, state: int) -> int:
        """The heading of a state (0 under ``omni``)."""
        return state & 3 if self.turning else 0

    def distances(self, goal: int) -> array[int]:
        """Actions from every state to standing on cell ``goal`` (any heading); cached."""
        table = self._cache.get(goal)
        if table is not None:
            self._cache.move_to_end(goal)
            return table
        self.prefetch([goal])
        return self._cache[goal]

    def cached(self, goal: int) -> bool:
        """Whether the table of ``goal`` is cached."""
        return goal in self._cache

    def missing(self, goals: Iterable[int]) -> list[int]:
        """The goals of ``goals`` without a cached table, sorted, each once."""
        cache = self._cache
        return sorted({g for g in goals if g not in cache})

    def prefetch(self, goals: Sequence[int]) -> None:
        """Compute the missing tables of ``goals`` together (one batched search)."""
        missing = self.missing(goals)
        if missing:
            self.offer(goal_tables(self.grid, self.turning, missing))

    def offer(self, tables: Mapping[int, array[int]]) -> None:
        """Cache tables computed elsewhere (:func:`goal_tables` of this grid and model, e.g. in
        another process); a table already cached is kept."""
        cache = self._cache
        for g, table in tables.items():
            if g not in cache:
                cache[g] = table
        while len(cache) > self._capacity:
            cache.popitem(last=False)


def goal_tables(grid: Grid, turning: bool, goals: Sequence[int]) -> dict[int, array[int]]:
    """The distance table of each goal cell (:meth:`StateSpace.distances`: int16, capped at
    :data:`UNREACHABLE`), searched in batches."""
    out: dict[int, array[int]] = {}
    for i in range(0, len(goals), 32):
        chunk = goals[i : i + 32]
        cells = [grid.cell(g) for g in chunk]
        found = (turning_distance_tables(grid, cells) if turning
                 else distance_tables(grid, cells))
        rows = np.where(found < 0, UNREACHABLE, np.minimum(found, UNREACHABLE))
        for g, row in zip(chunk, rows.astype(np.int16), strict=True):
            out[g] = array("h", row.tobytes())
    return out


@dataclass
class Window:
    """A planned window: ``states[j][r]`` for steps 0..steps, and for each robot the steps at
    which it reached each of its goals, in order (``reached[r][i]`` for ``goals[r][i]``)."""

    states: list[list[int]]
    reached: list[list[int]]


class WindowedPIBT:
    """1-robust PIBT over a :class:`StateSpace`, keeping priorities between calls."""

    def __init__(self, space: StateSpace, n_robots: int, seed: int = 0) -> None:
        self.space = space
        self.n = n_robots
        self.rng = random.Random(seed)
        self.elapsed = [0] * n_robots
        self.tie = [self.rng.random() for _ in range(n_robots)]
        n_cells = space.grid.size
        self._occupant = [-1] * n_cells
        self._reserved = [0] * n_cells
        self._planned = [0] * n_robots
        self._stamp = 0
        self._avoid = [0] * n_cells
        self._call = 0

    def plan(self, states: Sequence[int], goals: Sequence[Sequence[int]], steps: int,
             hold: Sequence[int] | None = None, avoid: Sequence[int] = ()) -> Window:
        """Plan ``steps`` timesteps from ``states``; ``goals[r]`` are robot r's next goal cells
        in order (empty: no goal; it waits unless asked to move away). Robot r waits through
        the first ``hold[r]`` steps (e.g. the committed actions it still has to do before it
        stands on its start state, so its new moves come when it can make them); the others
        plan around it, and enter no cell of ``avoid`` (e.g. cells a delayed robot will
        still drive through)."""
        space, n = self.space, self.n
        cell_of = space.cell_of
        cur = list(states)
        if len({cell_of[s] for s in cur}) != n:
            raise ValueError("two robots stand on the same cell")
        space.prefetch([g[0] for g in goals if g])
        progress = [0] * n
        reached: list[list[int]] = [[] for _ in range(n)]
        for r in range(n):
            self._arrive(r, cur[r], goals[r], progress, reached, 0)
        out = [cur]
        occupant = self._occupant
        self._call += 1
        for c in avoid:
            self._avoid[c] = self._call
        for r, s in enumerate(cur):
            occupant[cell_of[s]] = r
        for step in range(1, steps + 1):
            space.prefetch([g[progress[r]] for r, g in enumerate(goals) if progress[r] < len(g)])
            tables = [space.distances(g[progress[r]]) if progress[r] < len(g) else None
                      for r, g in enumerate(goals)]
            nxt = self._step(cur, tables, hold, step)
            for s in cur:
                occupant[cell_of[s]] = -1
            for r, s in enumerate(nxt):
                occupant[cell_of[s]] = r
                self._arrive(r, s, goals[r], progress, reached, step)
            out.append(nxt)
            cur = nxt
        for s in cur:
            occupant[cell_of[s]] = -1
        return Window(out, reached)

    def _arrive(self, r: int, state: int, goals: Sequence[int], progress: list[int],
                reached: list[list[int]], step: int) -> None:
        cell = self.space.cell_of[state]
        k = progress[r]
        hit = False
        while k < len(goals) and goals[k] == cell:
            reached[r].append(step)
            k += 1
            hit = True
        progress[r] = k
        if hit:
            self.elapsed[r] = 0
        elif k < len(goals):
            self.elapsed[r] += 1

    def _step(self, cur: list[int], tables: list[array[int] | None],
              hold: Sequence[int] | None, step: int) -> list[int]:
        self._stamp += 1
        stamp = self._stamp
        n = self.n
        nxt = list(cur)
        elapsed, tie = self.elapsed, self.tie
        order = sorted(range(n), key=lambda r: (tables[r] is None, -elapsed[r], -tie[r]))
        planned = self._planned
        if hold is not None:
            for r in range(n):
                if hold[r] >= step:
                    planned[r] = stamp
        for r in order:
            if planned[r] != stamp:
                self._decide(r, -1, cur, nxt, tables, 0)
        return nxt

    def _decide(self, r: int, pusher: int, cur: list[int], nxt: list[int],
                tables: list[array[int] | None], depth: int) -> None:
        """Choose robot r's next state (``pusher`` >= 0: that robot wants r's cell)."""
        stamp = self._stamp
        self._planned[r] = stamp
        space = self.space
        cell_of, occupant, reserved = space.cell_of, self._occupant, self._reserved
        avoid, call = self._avoid, self._call
        s = cur[r]
        c = cell_of[s]
        table = tables[r]
        rng = self.rng.random
        keyed = []
        for c2, es, turns, rs in space.options[s]:
            cost = table[es] + turns if table is not None else 0
            if c2 == c:
                # waiting: preferred on ties (no needless motion), last resort if asked to leave
                keyed.append((cost + (UNREACHABLE if pusher >= 0 else 0), 0, 0, rng(), c2, rs))
            else:
                keyed.append((cost, 1 if occupant[c2] < 0 else 2, turns, rng(), c2, rs))
        keyed.sort()
        for _, _, _, _, c2, rs in keyed:
            if c2 == c:
                nxt[r] = rs
                reserved[c] = stamp
                return
            if reserved[c2] == stamp or avoid[c2] == call:
                continue
            o = occupant[c2]
            if o >= 0:
                # 1-robust: a held cell cannot be entered now; ask its robot to clear it
                if o != pusher and self._planned[o] != stamp and depth < MAX_PUSH_DEPTH:
                    self._decide(o, r, cur, nxt, tables, depth + 1)
                continue
            nxt[r] = rs
            reserved[cell_of[rs]] = stamp  # the cell, or the own cell for a turn towards it
            return
        nxt[r] = s  # unreachable: waiting in place is always a candidate
        reserved[c] = stamp
