"""Sum-of-costs-optimal 1-robust Conflict-Based Search (CBS).

The high level is best-first on ``SOC + h`` with these improvements, each switchable through
:class:`CBSOptions` (the benchmark compares against all of them off):

* conflict choice: cardinal first, then semi-cardinal, then earliest, with conflicts classified
  on the agents' MDDs (multi-valued decision diagrams of their cheapest paths);
* ``h``: the minimum vertex cover of the graph of agent pairs that have a cardinal conflict or
  whose MDDs hold no conflict-free pair of paths (DG heuristic), admissible because each such
  edge forces one of its two agents to pay at least one more step; with ``weighted`` (WDG,
  by default under ``turning`` only)
  each edge weighs what the pair must pay together, ``Δ`` = its optimal 1-robust SOC under
  the node's constraints minus its current costs (a two-agent CBS, cached per pair and
  constraint sets; if that search hits its node budget, its best lower bound, at least 1),
  and ``h`` is the minimum weighted vertex cover (integers ``x_a`` with
  ``x_a + x_b >= Δ_ab``), admissible because the pairs' extra costs are paid by their agents;
* bypassing: a child that keeps the cost and has fewer conflicts replaces the parent's path;
* target reasoning: a conflict with an agent parked on its goal splits on that agent's arrival
  time (see :mod:`gateway.planning.cbs_conflicts`);
* rectangle reasoning (``omni`` only, see below);
* low level: space-time A* on exact distance tables, ties broken towards fewer conflicts.

Under the ``turning`` model the low level, the MDDs and the distance tables are over
``(cell, heading)`` states while constraints and conflicts stay on cells, so the conflict
splits, MDD cardinality, the DG heuristic, bypassing and target reasoning keep their proofs
(each is about which cells an agent can be on when, whatever its states are; an agent parked
on its goal holds the cell whatever it turns). Rectangle reasoning does not: its barrier proof
needs every cheapest path to reach cell c at exactly ``|c - start|`` (or one step later), and
under ``turning`` two cheapest paths reach the same cell at times that differ by their numbers
of turns (a staircase pays a turn per corner, an L-shaped path one), so barriers built on
turning costs could cut off every optimal plan. As written (both costs equal to the Manhattan
distances) it could never fire anyway: a rectangle needs both agents to move along both axes,
which takes a turn, so a turning cost always exceeds the Manhattan distance. It is switched off
for ``turning``.
"""

from __future__ import annotations

from collections import defaultdict
from collections.abc import Sequence
from copy import copy
from dataclasses import dataclass
from heapq import heappop, heappush

from gateway.planning.cbs_conflicts import Branch, Conflict, pair_conflicts, rectangle
from gateway.planning.constraints import FINISH, Constraint, ConstraintTable, build_table
from gateway.planning.grid import Grid
from gateway.planning.low_level import (
    AvoidanceTable,
    build_mdd,
    mdd_always_visits,
    mdds_compatible,
    space_time_astar,
)
from gateway.planning.motion import Motion
from gateway.planning.plan import Deadline, NoSolution, Solution
from gateway.planning.problem import Forbidden, Place, Problem

NON_CARDINAL, SEMI_CARDINAL, CARDINAL = 0, 1, 2

PAIR_BUDGET = 32
"""Node expansions a WDG edge's two-agent CBS may make before it settles for a lower bound."""

WEIGHTED_COVER_MAX = 12
"""Largest connected component of the WDG solved exactly (larger, or with a weight above
:data:`WEIGHT_MAX`: a lower bound, see :func:`min_weighted_vertex_cover`)."""

WEIGHT_MAX = 4
"""Largest edge weight of a component solved exactly."""

NO_PAIR_PLAN = 1 << 20
"""The weight of a pair that has no joint plan under the node's constraints."""

DENSE_AVOIDANCE = 1 << 21
"""Largest (cells x timesteps) for which the conflict-avoidance table is a flat list."""


@dataclass(frozen=True)
class CBSOptions:
    """Switches for the CBS improvements (all on by default)."""

    cardinal: bool = True
    heuristic: bool = True
    dependency: bool = True
    rectangle: bool = True
    bypass: bool = True
    target: bool = True
    avoidance: bool = True
    weighted: bool | None = None
    """WDG instead of DG: on, off, or None = under ``turning`` only (under ``omni`` the DG is
    nearly as strong on the benchmark and the pair searches cost more than they save)."""


_PairNode = tuple[int, int, tuple[Constraint, ...], tuple[Constraint, ...], tuple[int, ...],
                  tuple[int, ...]]
"""A node of a WDG edge's two-agent CBS: (joint cost, tie, constraints on each agent, cell
paths of each)."""


class _Node:
    """A high-level node: constraints (a chain to the root), paths and their conflicts."""

    __slots__ = (
        "best", "branch", "conflicts", "costs", "deps", "g", "h", "h_done", "mdds", "nconf",
        "parent", "paths", "states",
    )

    def __init__(
        self,
        parent: _Node | None,
        branch: Branch | None,
        states: list[tuple[int, ...]],
        paths: list[tuple[int, ...]],
        conflicts: dict[tuple[int, int], list[Conflict]],
        mdds: dict[int, list[frozenset[int]]],
        best: dict[tuple[int, int], tuple[int, Conflict]],
    ) -> None:
        self.parent = parent
        self.branch = branch
        self.states = states
        self.paths = paths
        self.costs = [len(p) - 1 for p in paths]
        self.g = sum(self.costs)
        self.h = 0
        self.h_done = False
        self.conflicts = conflicts
        self.nconf = sum(len(c) for c in conflicts.values())
        self.mdds = mdds
        self.best = best
        self.deps: dict[tuple[int, int], bool] = {}


class _Search:
    """One CBS run on one instance."""

    def __init__(
        self,
        grid: Grid,
        starts: Sequence[Place],
        goals: Sequence[Place],
        forbidden: Sequence[Forbidden],
        deadline: Deadline,
        options: CBSOptions,
        motion: Motion,
    ) -> None:
        problem = Problem(grid, starts, goals, forbidden, motion)
        self.problem = problem
        self.grid = grid
        self.model = problem.model
        self.size = problem.size
        self.starts = problem.starts
        self.goals = problem.goals
        self.h = problem.h
        self.base = problem.base
        self.start_cells = problem.start_cells
        self.goal_cells = problem.goal_cells
        self.manhattan = [
            abs(s[0] - g[0]) + abs(s[1] - g[1])
            for s, g in zip(self.start_cells, self.goal_cells, strict=True)
        ]
        self.deadline = deadline
        self.options = options
        self.expanded = 0
        self.tie = 0
        self.weighted = options.weighted if options.weighted is not None else (
            motion == "turning")
        self.pair_deltas: dict[tuple[int, int, tuple[Constraint, ...], tuple[Constraint, ...]],
                               int] = {}

    # ----- low level -------------------------------------------------------------------------

    def _table(
        self, node: _Node | None, agent: int, extra: Branch | None = None
    ) -> ConstraintTable:
        cons = list(self.base)
        if extra is not None:
            cons.extend(extra[1])
        cons.extend(self._constraints(node, agent))
        return build_table(self.size, cons)

    @staticmethod
    def _constraints(node: _Node | None, agent: int) -> tuple[Constraint, ...]:
        """The branch constraints on ``agent`` from ``node`` up to the root."""
        cons: list[Constraint] = []
        while node is not None:
            b = node.branch
            if b is not None and b[0] == agent:
                cons.extend(b[1])
            node = node.parent
        return tuple(cons)

    def _occupancy(self, paths: Sequence[tuple[int, ...] | None]) -> AvoidanceTable:
        """Conflict counts of a visit to every (cell, time) against all the given paths."""
        size = self.size
        horizon = max((len(p) for p in paths if p is not None), default=0)
        counts: list[int] | defaultdict[int, int]
        if (horizon + 1) * size <= DENSE_AVOIDANCE:
            counts = [0] * ((horizon + 1) * size)
        else:
            counts = defaultdict(int)
        stays: dict[int, int] = {}
        for p in paths:
            if p is not None:
                self._count(counts, p, 1)
                stays[p[-1]] = max(len(p) - 2, 0)
        return AvoidanceTable(counts, stays, horizon)

    def _count(
        self, counts: list[int] | defaultdict[int, int], path: tuple[int, ...], sign: int
    ) -> None:
        """Add (sign 1) or remove (sign -1) one path's 1-robust footprint: cell v at times
        t-1, t, t+1 for each step t before its end (its goal stay is in ``stays``)."""
        size = self.size
        for t in range(len(path) - 1):
            v = path[t]
            if t:
                counts[(t - 1) * size + v] += sign
            counts[t * size + v] += sign
            counts[(t + 1) * size + v] += sign

    def _avoidance(self, everyone: AvoidanceTable, path: tuple[int, ...]) -> AvoidanceTable:
        """``everyone``'s table without the agent whose current path is ``path``."""
        counts = copy(everyone.counts)
        self._count(counts, path, -1)
        stays = dict(everyone.stays)
        del stays[path[-1]]
        return AvoidanceTable(counts, stays, everyone.horizon)

    def _plan(
        self, agent: int, table: ConstraintTable, avoid: AvoidanceTable | None
    ) -> tuple[tuple[int, ...], tuple[int, ...]] | None:
        """The agent's new path as (states, cells), or None if it has none."""
        states = space_time_astar(
            self.model, self.starts[agent], self.goals[agent], self.h[agent], table, avoid,
            self.deadline,
        )
        if states is None:
            return None
        if self.problem.motion == "omni":
            path = tuple(states)
            return path, path
        return tuple(states), self.problem.cells_of(states)

    # ----- nodes -----------------------------------------------------------------------------

    def root(self) -> _Node:
        n = len(self.starts)
        paths: list[tuple[int, ...] | None] = [None] * n
        states: list[tuple[int, ...]] = []
        for k in range(n):
            avoid = self._occupancy(paths) if self.options.avoidance else None
            got = self._plan(k, self._table(None, k), avoid)
            if got is None:
                raise NoSolution(f"agent {k} has no path under the forbidden windows")
            states.append(got[0])
            paths[k] = got[1]
        full = [p for p in paths if p is not None]
        conflicts: dict[tuple[int, int], list[Conflict]] = {}
        for i in range(n):
            for j in range(i + 1, n):
                found = pair_conflicts(i, full[i], j, full[j], self.options.target)
                if found:
                    conflicts[i, j] = found
        return _Node(None, None, states, full, conflicts, {}, {})

    def child(
        self, node: _Node, branch: Branch, everyone: AvoidanceTable | None
    ) -> _Node | None:
        """The node with ``branch`` added and its agent replanned (None if it has no path).

        ``everyone`` is the node's occupancy table, if conflicts are to be avoided."""
        agent = branch[0]
        table = self._table(node, agent, branch)
        avoid = None if everyone is None else self._avoidance(everyone, node.paths[agent])
        got = self._plan(agent, table, avoid)
        if got is None:
            return None
        states = list(node.states)
        states[agent] = got[0]
        paths = list(node.paths)
        paths[agent] = got[1]
        target = self.options.target
        conflicts = {pair: c for pair, c in node.conflicts.items() if agent not in pair}
        for j in range(len(paths)):
            if j == agent:
                continue
            i, k = (agent, j) if agent < j else (j, agent)
            found = pair_conflicts(i, paths[i], k, paths[k], target)
            if found:
                conflicts[i, k] = found
        mdds = {a: m for a, m in node.mdds.items() if a != agent}
        best = {pair: v for pair, v in node.best.items() if agent not in pair}
        ch = _Node(node, branch, states, paths, conflicts, mdds, best)
        ch.deps = {pair: v for pair, v in node.deps.items() if agent not in pair}
        ch.h = max(0, node.h - (ch.g - node.g))
        return ch

    def _mdd(self, node: _Node, agent: int) -> list[frozenset[int]]:
        mdd = node.mdds.get(agent)
        if mdd is None:
            table = self._table(node, agent)
            mdd = build_mdd(
                self.model, self.starts[agent], self.h[agent], table, node.costs[agent]
            )
            node.mdds[agent] = mdd
        return mdd

    def _raises_cost(self, node: _Node, branch: Branch) -> bool:
        agent, ((cell, t0, t1),) = branch
        if cell == FINISH:
            return node.costs[agent] <= t0
        return mdd_always_visits(
            self.model, self._mdd(node, agent), self.goals[agent], cell, t0, t1
        )

    def classify(self, node: _Node, conflict: Conflict) -> int:
        """CARDINAL, SEMI_CARDINAL or NON_CARDINAL for a range or target conflict."""
        return int(self._raises_cost(node, conflict[1])) + int(
            self._raises_cost(node, conflict[2])
        )

    def _rectangle(self, node: _Node, i: int, j: int, time: int) -> Conflict | None:
        manhattan = self.manhattan
        if node.costs[i] != manhattan[i] or node.costs[j] != manhattan[j]:
            return None
        found = rectangle(
            i, self.start_cells[i], self.goal_cells[i], j, self.start_cells[j],
            self.goal_cells[j], self.grid.width,
        )
        return None if found is None else (time, *found)

    def pair_best(self, node: _Node, pair: tuple[int, int]) -> tuple[int, Conflict]:
        """The pair's conflict to split and its class (cached on the node)."""
        got = node.best.get(pair)
        if got is not None:
            return got
        found = node.conflicts[pair]
        best = found[0]
        kind = NON_CARDINAL
        for c in found:
            k = self.classify(node, c)
            if k > kind or (k == kind and c[0] < best[0]):
                best, kind = c, k
        if kind < CARDINAL and self.options.rectangle and self.problem.motion == "omni":
            rect = self._rectangle(node, pair[0], pair[1], min(c[0] for c in found))
            if rect is not None:
                best, kind = rect, CARDINAL
        node.best[pair] = (kind, best)
        return kind, best

    def choose(self, node: _Node) -> Conflict:
        """The conflict to split: most cardinal, then earliest (earliest only if not
        ``options.cardinal``)."""
        if not self.options.cardinal:
            return min((c for found in node.conflicts.values() for c in found),
                       key=lambda c: c[0])
        best: Conflict | None = None
        best_key = (0, 0)
        for pair in node.conflicts:
            kind, c = self.pair_best(node, pair)
            key = (-kind, c[0])
            if best is None or key < best_key:
                best, best_key = c, key
        assert best is not None
        return best

    def heuristic(self, node: _Node) -> int:
        """Minimum vertex cover of the pairs that have a cardinal conflict or are dependent
        (weighted by the pairs' extra costs with ``options.weighted``)."""
        edges = [
            pair for pair in node.conflicts
            if self.pair_best(node, pair)[0] == CARDINAL
            or (self.options.dependency and self.dependent(node, pair))
        ]
        if not self.weighted:
            return min_vertex_cover(edges)
        weights = {pair: self.pair_delta(node, pair) for pair in edges}
        if any(w >= NO_PAIR_PLAN for w in weights.values()):
            return NO_PAIR_PLAN  # a pair without a joint plan: so is the node
        return min_weighted_vertex_cover(weights)

    def pair_delta(self, node: _Node, pair: tuple[int, int]) -> int:
        """What agents ``pair`` must pay together beyond their costs in ``node`` (at least 1:
        the pair is an edge of the dependency graph), by a two-agent CBS (cached)."""
        a, b = pair
        cons_a, cons_b = self._constraints(node, a), self._constraints(node, b)
        key = (a, b, cons_a, cons_b)
        got = self.pair_deltas.get(key)
        if got is None:
            got = max(1, self._pair_cbs(node, pair, cons_a, cons_b))
            self.pair_deltas[key] = got
        return got

    def _pair_cbs(self, node: _Node, pair: tuple[int, int], cons_a: tuple[Constraint, ...],
                  cons_b: tuple[Constraint, ...]) -> int:
        """The pair's optimal joint cost minus its current one (a lower bound if the search
        ran out of its budget; :data:`NO_PAIR_PLAN` if it has no joint plan)."""
        a, b = pair
        base = node.costs[a] + node.costs[b]
        target = self.options.target
        tie = 0
        open_list: list[_PairNode] = [(base, 0, cons_a, cons_b, node.paths[a], node.paths[b])]
        for _ in range(PAIR_BUDGET):
            if not open_list:
                return NO_PAIR_PLAN
            g, _, ca, cb, pa, pb = heappop(open_list)
            found = pair_conflicts(a, pa, b, pb, target)
            if not found:
                return g - base
            for agent, extra in found[0][1:]:
                na, nb = (ca + extra, cb) if agent == a else (ca, cb + extra)
                got = self._plan(agent, build_table(
                    self.size, [*self.base, *(na if agent == a else nb)]), None)
                if got is None:
                    continue
                qa, qb = (got[1], pb) if agent == a else (pa, got[1])
                tie += 1
                heappush(open_list, (len(qa) + len(qb) - 2, tie, na, nb, qa, qb))
        return open_list[0][0] - base if open_list else NO_PAIR_PLAN

    def dependent(self, node: _Node, pair: tuple[int, int]) -> bool:
        """True if no two paths at the agents' current costs avoid each other (cached)."""
        got = node.deps.get(pair)
        if got is None:
            a, b = pair
            got = not mdds_compatible(self.model, self._mdd(node, a), self._mdd(node, b))
            node.deps[pair] = got
        return got

    # ----- high level ------------------------------------------------------------------------

    def push(self, open_list: list[tuple[int, int, int, _Node]], node: _Node) -> None:
        self.tie += 1
        heappush(open_list, (node.g + node.h, node.nconf, self.tie, node))

    def run(self) -> Solution:
        open_list: list[tuple[int, int, int, _Node]] = []
        self.push(open_list, self.root())
        opts = self.options
        while open_list:
            if self.deadline.expired():
                raise NoSolution("deadline expired in CBS", timed_out=True)
            f, _, _, node = heappop(open_list)
            if node.nconf == 0:
                return self.solution(node)
            if opts.heuristic and not node.h_done:
                node.h_done = True
                node.h = max(node.h, self.heuristic(node))
                if node.g + node.h > f:
                    self.push(open_list, node)
                    continue
            self.expanded += 1
            conflict = self.choose(node)
            children = []
            bypassed = False
            everyone = self._occupancy(node.paths) if opts.avoidance else None
            for branch in conflict[1:]:
                ch = self.child(node, branch, everyone)
                if ch is None:
                    continue
                if opts.bypass and ch.g == node.g and ch.nconf < node.nconf:
                    self.adopt(node, ch, branch[0])
                    bypassed = True
                    break
                children.append(ch)
            if bypassed:
                self.push(open_list, node)
                continue
            for ch in children:
                self.push(open_list, ch)
        raise NoSolution("no 1-robust plan exists")

    def adopt(self, node: _Node, ch: _Node, agent: int) -> None:
        """Bypass: take the child's path for ``agent`` into ``node`` (same constraints)."""
        node.states = ch.states
        node.paths = ch.paths
        node.costs = ch.costs
        node.conflicts = ch.conflicts
        node.nconf = ch.nconf
        node.best = {pair: v for pair, v in node.best.items() if agent not in pair}
        node.deps = {pair: v for pair, v in node.deps.items() if agent not in pair}
        node.h_done = False

    def solution(self, node: _Node) -> Solution:
        plan = self.problem.plan_of(node.states)
        return Solution(plan, optimal=True, expanded_nodes=self.expanded)


def min_vertex_cover(edges: Sequence[tuple[int, int]]) -> int:
    """Size of a minimum vertex cover of a small graph (exact branching on an edge's ends)."""
    memo: dict[frozenset[tuple[int, int]], int] = {}

    def cover(es: frozenset[tuple[int, int]]) -> int:
        if not es:
            return 0
        got = memo.get(es)
        if got is not None:
            return got
        u, v = min(es)
        best = 1 + min(
            cover(frozenset(e for e in es if u not in e)),
            cover(frozenset(e for e in es if v not in e)),
        )
        memo[es] = best
        return best

    return cover(frozenset(edges))


def min_weighted_vertex_cover(weights: dict[tuple[int, int], int]) -> int:
    """Least ``sum(x_v)`` over integers ``x_v >= 0`` with ``x_a + x_b >= w`` for every edge
    ``(a, b)`` of weight ``w``: exact per connected component of at most
    :data:`WEIGHTED_COVER_MAX` vertices and weights of at most :data:`WEIGHT_MAX`, else a lower
    bound: the larger of the component's unweighted cover (every edge weighs at least 1) and
    the weight of a greedy matching (its edges need disjoint vertices)."""
    nbrs: dict[int, dict[int, int]] = defaultdict(dict)
    for (a, b), w in weights.items():
        nbrs[a][b] = nbrs[b][a] = w
    total, seen = 0, set()
    for v0 in sorted(nbrs):
        if v0 in seen:
            continue
        comp, stack = [], [v0]
        seen.add(v0)
        while stack:
            v = stack.pop()
            comp.append(v)
            for u in nbrs[v]:
                if u not in seen:
                    seen.add(u)
                    stack.append(u)
        edges = {e: w for e, w in weights.items() if e[0] in comp}
        if len(comp) > WEIGHTED_COVER_MAX or max(edges.values()) > WEIGHT_MAX:
            matched: set[int] = set()
            matching = 0
            for (a, b), w in sorted(edges.items(), key=lambda item: -item[1]):
                if a not in matched and b not in matched:
                    matched |= {a, b}
                    matching += w
            total += max(matching, min_vertex_cover(list(edges)))
            continue
        comp.sort(key=lambda v: -len(nbrs[v]))
        total += _weighted_cover(comp, nbrs)
    return total


def _weighted_cover(comp: list[int], nbrs: dict[int, dict[int, int]]) -> int:
    """Exact weighted vertex cover of one component, vertices assigned in ``comp`` order."""
    best = sum(max(nbrs[v].values()) for v in comp)
    value: dict[int, int] = {}

    def assign(i: int, cost: int) -> None:
        nonlocal best
        if cost >= best:
            return
        if i == len(comp):
            best = cost
            return
        v = comp[i]
        low = max([w - value[u] for u, w in nbrs[v].items() if u in value] + [0])
        for x in range(low, max(nbrs[v].values()) + 1):
            value[v] = x
            assign(i + 1, cost + x)
        del value[v]

    assign(0, 0)
    return best


def solve_cbs(
    grid: Grid,
    starts: Sequence[Place],
    goals: Sequence[Place],
    *,
    deadline: Deadline,
    forbidden: Sequence[Forbidden] = (),
    options: CBSOptions = CBSOptions(),
    motion: Motion = "omni",
) -> Solution:
    """An SOC-optimal 1-robust plan (DESIGN section 2) found by CBS.

    Under ``motion="turning"`` starts are ``(x, y, heading)`` and goals ``(x, y)`` (any final
    heading) or ``(x, y, heading)``. ``forbidden`` cells are closed to every agent during their
    time windows. Raises ``NoSolution`` if there is none (``timed_out=True`` if the deadline
    expired first) and ``ValueError`` on a malformed instance.
    """
    return _Search(grid, starts, goals, forbidden, deadline, options, motion).run()
