"""Single-agent planning in space-time: motion models, A* under constraints, and MDDs.

The low level works on *states* (ints) produced by a motion model; constraints and conflicts are
on *cells*. With the ``omni`` model a state is the cell's flat id; the ``turning`` model numbers
``(cell, heading)`` pairs ``4 * cell + heading`` and maps each to its cell through ``cells``.
A state is a goal state when its heuristic (an exact distance table) is 0: the goal cell under
``omni``, the goal cell with any heading (or the fixed goal heading) under ``turning``.
"""

from __future__ import annotations

import weakref
from collections import defaultdict
from collections.abc import Sequence
from dataclasses import dataclass, field
from heapq import heappop, heappush

from gateway.planning.constraints import INF, ConstraintTable
from gateway.planning.distance import distance_tables, turning_distance_tables
from gateway.planning.grid import Grid
from gateway.planning.motion import HEADING_MOVES, Motion
from gateway.planning.plan import Deadline, NoSolution

DEADLINE_EVERY = 512
"""The low level asks the deadline once per this many expansions."""


@dataclass(frozen=True, eq=False)
class OmniModel:
    """The ``omni`` motion model: wait or move to a free 4-neighbour, one timestep each.

    ``succ[s]`` lists the successor states of state ``s`` (waiting first); ``cells[s]`` is the
    cell of state ``s`` (the identity here).
    """

    grid: Grid
    succ: tuple[tuple[int, ...], ...] = field(init=False, repr=False)
    cells: tuple[int, ...] = field(init=False, repr=False)

    def __post_init__(self) -> None:
        n = self.grid.size
        flat = self.grid.free.ravel()
        succ = tuple((i, *self.grid.neighbour_ids(i)) if flat[i] else () for i in range(n))
        object.__setattr__(self, "succ", succ)
        object.__setattr__(self, "cells", tuple(range(n)))

    def state(self, cell: int, heading: int = 0) -> int:
        """The state of an agent standing on ``cell`` (the heading is ignored)."""
        return cell

    def heading(self, state: int) -> int:
        """Always 0: ``omni`` states have no heading."""
        return 0

    def heuristics(self, goals: Sequence[int],
                   goal_headings: Sequence[int | None] | None = None) -> list[list[int]]:
        """For each goal cell, exact moves-to-go from every state (-1 where unreachable)."""
        cell = self.grid.cell
        result: list[list[int]] = distance_tables(self.grid, [cell(g) for g in goals]).tolist()
        return result


@dataclass(frozen=True, eq=False)
class TurningModel:
    """The ``turning`` motion model: state ``4 * cell + heading``; wait, turn 90 degrees either
    way in place, or move one cell forward along the heading, one timestep each.

    ``succ[s]`` lists the successor states of state ``s`` (waiting first, then the turns
    clockwise and counter-clockwise, then forward if that cell is free); ``cells[s]`` is the
    cell of state ``s``.
    """

    grid: Grid
    succ: tuple[tuple[int, ...], ...] = field(init=False, repr=False)
    cells: tuple[int, ...] = field(init=False, repr=False)

    def __post_init__(self) -> None:
        grid = self.grid
        w, h = grid.width, grid.height
        flat = grid.free.ravel()
        succ: list[tuple[int, ...]] = []
        for c in range(grid.size):
            x, y = c % w, c // w
            for d, (dx, dy) in enumerate(HEADING_MOVES):
                if not flat[c]:
                    succ.append(())
                    continue
                s = 4 * c + d
                out = [s, 4 * c + (d + 1) % 4, 4 * c + (d + 3) % 4]
                nx, ny = x + dx, y + dy
                if 0 <= nx < w and 0 <= ny < h and flat[ny * w + nx]:
                    out.append(4 * (ny * w + nx) + d)
                succ.append(tuple(out))
        object.__setattr__(self, "succ", tuple(succ))
        object.__setattr__(self, "cells", tuple(s >> 2 for s in range(4 * grid.size)))

    def state(self, cell: int, heading: int = 0) -> int:
        """The state of an agent standing on ``cell`` with ``heading``."""
        return 4 * cell + heading

    def heading(self, state: int) -> int:
        """The heading of a state."""
        return state & 3

    def heuristics(self, goals: Sequence[int],
                   goal_headings: Sequence[int | None] | None = None) -> list[list[int]]:
        """For each goal cell (with its heading if fixed, any heading if None), exact
        timesteps-to-go from every state (-1 where unreachable)."""
        cell = self.grid.cell
        result: list[list[int]] = turning_distance_tables(
            self.grid, [cell(g) for g in goals], goal_headings).tolist()
        return result


MotionModel = OmniModel | TurningModel
"""A motion model the planners accept."""

_MODELS: weakref.WeakKeyDictionary[Grid, dict[str, MotionModel]] = weakref.WeakKeyDictionary()


def motion_model(grid: Grid, motion: Motion) -> MotionModel:
    """The model of ``motion`` on ``grid`` (cached per grid: building one is O(cells))."""
    models = _MODELS.setdefault(grid, {})
    model = models.get(motion)
    if model is None:
        if motion == "omni":
            model = OmniModel(grid)
        elif motion == "turning":
            model = TurningModel(grid)
        else:
            raise ValueError(f"unknown motion model {motion!r}: give omni or turning")
        models[motion] = model
    return model


@dataclass(slots=True)
class AvoidanceTable:
    """Other agents' occupancy, used only to break ties towards fewer conflicts.

    ``counts[t * size + cell]`` is how many other agents a visit of ``cell`` at ``t`` conflicts
    with (a list, dense, where times past its end count 0; or a defaultdict, sparse, for large
    maps); ``stays[cell]`` is the time from which an agent
    parked on ``cell`` conflicts with a visit; after ``horizon`` nothing changes.
    """

    counts: list[int] | defaultdict[int, int]
    stays: dict[int, int]
    horizon: int


def space_time_astar(
    model: MotionModel,
    start: int,
    goal: int,
    h: list[int],
    table: ConstraintTable,
    avoid: AvoidanceTable | None,
    deadline: Deadline,
    max_expansions: int | None = None,
) -> list[int] | None:
    """A cheapest path of states from ``start`` that ends in a goal state (``h == 0``, on cell
    ``goal``) and may stay there.

    The path ends at time T with ``T > table.goal_block(goal)``, so staying on the goal after T
    breaks no constraint. Among cheapest paths it returns one with fewest conflicts counted by
    ``avoid``. Returns None if no path exists (or none was found within ``max_expansions``
    expansions, if given); raises ``NoSolution(timed_out=True)`` when the
    deadline expires.
    """
    size = table.size
    succ = model.succ
    cells = model.cells
    blocked = table.blocked
    permanent = table.permanent
    goal_block = table.goal_block(goal)
    if goal_block >= INF or h[start] < 0 or table.forbids(cells[start], 0):
        return None
    counts = avoid.counts if avoid is not None else []
    ncounts = len(counts) if isinstance(counts, list) else INF
    stays = avoid.stays if avoid is not None else {}
    horizon = max(table.horizon, avoid.horizon if avoid is not None else 0, goal_block + 1)
    nstates = len(succ)
    floor = goal_block + 1
    f0 = max(h[start], floor)
    open_list: list[tuple[int, int, int, int, int, int, object]] = [
        (f0, 0, h[start], 0, start, 0, None)
    ]
    closed: set[int] = set()
    tie = 0
    expanded = 0
    while open_list:
        entry = heappop(open_list)
        _, nc, _, _, s, t, _ = entry
        key = (t if t < horizon else horizon) * nstates + s
        if key in closed:
            continue
        closed.add(key)
        if h[s] == 0 and t >= floor:
            path = []
            node: object = entry
            while node is not None:
                path.append(node[4])  # type: ignore[index]
                node = node[6]  # type: ignore[index]
            path.reverse()
            return path
        expanded += 1
        if expanded % DEADLINE_EVERY == 0:
            if deadline.expired():
                raise NoSolution("deadline expired in the low-level search", timed_out=True)
            if max_expansions is not None and expanded >= max_expansions:
                return None
        nt = t + 1
        tk = nt * size
        ckey = (nt if nt < horizon else horizon) * nstates
        for u in succ[s]:
            hu = h[u]
            if hu < 0 or ckey + u in closed:
                continue
            c = cells[u]
            if tk + c in blocked:
                continue
            if permanent:
                first = permanent.get(c)
                if first is not None and nt >= first:
                    continue
            fu = nt + hu
            if fu < floor:
                fu = floor
            nu = nc + counts[tk + c] if tk + c < ncounts else nc
            if stays:
                st = stays.get(c)
                if st is not None and nt >= st:
                    nu += 1
            tie += 1
            heappush(open_list, (fu, nu, hu, tie, u, nt, entry))
    return None


def build_mdd(
    model: MotionModel, start: int, h: list[int], table: ConstraintTable, cost: int
) -> list[frozenset[int]]:
    """Layers of the multi-valued decision diagram: all cost-``cost`` paths under ``table``.

    ``mdd[t]`` holds the states that some such path visits at time t; ``mdd[cost]`` holds goal
    states (``h == 0``) only. ``cost`` must be the agent's optimal cost under ``table``.
    """
    succ = model.succ
    cells = model.cells
    size = table.size
    blocked = table.blocked
    permanent = table.permanent
    layers: list[set[int]] = [{start}]
    for t in range(1, cost + 1):
        budget = cost - t
        tk = t * size
        cur: set[int] = set()
        for s in layers[-1]:
            for u in succ[s]:
                if u in cur or not 0 <= h[u] <= budget:
                    continue
                c = cells[u]
                if tk + c in blocked or permanent.get(c, INF) <= t:
                    continue
                cur.add(u)
        layers.append(cur)
    layers[cost] = {s for s in layers[cost] if h[s] == 0}
    for t in range(cost - 1, -1, -1):
        nxt = layers[t + 1]
        layers[t] = {s for s in layers[t] if any(u in nxt for u in succ[s])}
    return [frozenset(layer) for layer in layers]


def mdd_always_visits(
    model: MotionModel, mdd: list[frozenset[int]], goal: int, cell: int, t0: int, t1: int
) -> bool:
    """True if every path of the MDD (staying on ``goal`` after its end) is on ``cell`` at
    some time in ``[t0, t1]``: a constraint forbidding that range raises the agent's cost."""
    cost = len(mdd) - 1
    if cell == goal and t1 >= cost:
        return True
    if t0 > cost:
        return False
    cells = model.cells
    succ = model.succ
    cur = {s for s in mdd[t0] if cells[s] != cell}
    for t in range(t0 + 1, min(t1, cost) + 1):
        if not cur:
            return True
        layer = mdd[t]
        cur = {u for s in cur for u in succ[s] if u in layer and cells[u] != cell}
    return not cur


def mdds_compatible(
    model: MotionModel, mdd_a: list[frozenset[int]], mdd_b: list[frozenset[int]]
) -> bool:
    """True if some path of each MDD (each staying on its goal after its end) make a
    conflict-free pair under the 1-robust rule; False means one of the two agents must pay
    more than its current cost."""
    succ = model.succ
    cells = model.cells
    last = max(len(mdd_a), len(mdd_b)) - 1
    frontier = {(s, u) for s in mdd_a[0] for u in mdd_b[0] if cells[s] != cells[u]}
    for t in range(1, last + 1):
        la = mdd_a[min(t, len(mdd_a) - 1)]
        lb = mdd_b[min(t, len(mdd_b) - 1)]
        nxt: set[tuple[int, int]] = set()
        for s, u in frontier:
            cs, cu = cells[s], cells[u]
            for s2 in succ[s]:
                if s2 not in la:
                    continue
                c2 = cells[s2]
                if c2 == cu:
                    continue  # a enters the cell b just left
                for u2 in succ[u]:
                    if u2 in lb:
                        d2 = cells[u2]
                        if d2 != c2 and d2 != cs:
                            nxt.add((s2, u2))
        if not nxt:
            return False
        frontier = nxt
    return True
