"""The Action Dependency Graph (DESIGN section 2) in compact, flat arrays.

Vertices are numbered robot by robot: robot ``k`` owns the ids ``first[k] .. first[k+1]-1`` in
the order of its path, so its Type 1 predecessor of ``v`` is ``v - 1`` (when ``v > first[k]``).
Under the ``turning`` motion model (``headings`` given) a turn is a vertex like any other
action; it holds its cell, so it is never the tail or head of a Type 2 edge. Type 2 edges are
stored twice, CSR-style: ``t2_pred[t2_pred_ptr[v]:t2_pred_ptr[v+1]]`` are the
tails of the Type 2 edges into ``v`` and ``t2_succ[...]`` the heads of those out of ``v``;
``pred``/``succ`` (with ``pred_ptr``/``succ_ptr``) hold all edges, Type 1 included.
"""

from __future__ import annotations

import copy
from bisect import bisect_right
from collections.abc import Collection, Iterator

from gateway.execution.actions import ActionKind, action_kind
from gateway.execution.errors import ExecutionError
from gateway.planning.grid import Cell
from gateway.planning.plan import Plan


def _csr(n: int, pairs: list[tuple[int, int]]) -> tuple[list[int], list[int]]:
    """Pointer and index lists of ``pairs`` (key, value) grouped by key, values sorted."""
    pairs.sort()
    ptr = [0] * (n + 1)
    for key, _ in pairs:
        ptr[key + 1] += 1
    for i in range(n):
        ptr[i + 1] += ptr[i]
    return ptr, [value for _, value in pairs]


class ADG:
    """Action Dependency Graph of a plan: one vertex per action, Type 1 and Type 2 edges.

    With ``drop_waits`` the wait actions get no vertex (Hönig's original graph), and so do the
    waits of ``gated`` (``(robot, path index)`` pairs; :func:`gated_waits`): those a robot
    would make before a move into a cell that is blocked, which then starts as soon as the
    cell is free instead. A wait is never the tail or head of a Type 2 edge, so dropping one
    keeps every ordering of the plan. The action numbers seen from outside stay the path
    indices ``i`` of ``a_i^k`` either way.
    A ``turning`` plan (``plan.headings``) makes its turns actions; a turn is never dropped.
    """

    def __init__(self, plan: Plan, *, drop_waits: bool = False,
                 gated: frozenset[tuple[int, int]] = frozenset()) -> None:
        paths = plan.paths
        self.n_robots = len(paths)
        self.drop_waits = drop_waits
        self.gated = gated
        self.headings = plan.headings
        if self.headings is not None and len(self.headings) != len(paths):
            raise ExecutionError(f"{len(self.headings)} heading sequences for {len(paths)} "
                                 "robots")
        self.first: list[int] = [0]
        self.robot_of: list[int] = []
        self.step_of: list[int] = []
        self.src: list[Cell] = []
        self.dst: list[Cell] = []
        self.kind: list[ActionKind] = []
        # flat lookup (robot, path index) -> vertex or -1, with per-robot offsets
        self._action_first: list[int] = [0]
        self._vertex_at: list[int] = []
        for k, path in enumerate(paths):
            if not path:
                raise ExecutionError(f"robot {k} has an empty path")
            hs = None if self.headings is None else self.headings[k]
            if hs is not None and len(hs) != len(path):
                raise ExecutionError(f"robot {k} has {len(hs)} headings for {len(path)} cells")
            for i in range(len(path) - 1):
                try:
                    kind = action_kind(path[i], path[i + 1], None if hs is None else hs[i],
                                       None if hs is None else hs[i + 1])
                except ExecutionError as exc:
                    raise ExecutionError(f"robot {k} action {i}: {exc}") from None
                if kind == "wait" and (drop_waits or (k, i) in gated):
                    self._vertex_at.append(-1)
                    continue
                self._vertex_at.append(len(self.robot_of))
                self.robot_of.append(k)
                self.step_of.append(i)
                self.src.append(path[i])
                self.dst.append(path[i + 1])
                self.kind.append(kind)
            self.first.append(len(self.robot_of))
            self._action_first.append(len(self._vertex_at))
        self.n_vertices = len(self.robot_of)
        firsts = set(self.first)
        self.is_first = bytearray(v in firsts for v in range(self.n_vertices))
        self._set_edges(self._type2_edges(), self.step_of)

    def _set_edges(self, edges: list[tuple[int, int]], level: list[int]) -> None:
        """Install the Type 2 ``edges`` (tail, head) and the Type 1 chain, with ``level``: a
        number per vertex that grows along every edge (the topological order's key)."""
        self.level = level
        """Grows along every edge: the plan step, or (rescheduled) the longest path from a
        source; :class:`~gateway.execution.oneshot.monitor.Monitor` evaluates vertices by level."""
        self.t2_pred_ptr, self.t2_pred = _csr(self.n_vertices, [(h, t) for t, h in edges])
        self.t2_succ_ptr, self.t2_succ = _csr(self.n_vertices, [(t, h) for t, h in edges])
        # all edges (Type 1 and 2) in CSR form, for the monitor's inner loop
        type1 = [(v - 1, v) for v in range(self.n_vertices) if not self.is_first[v]]
        self.pred_ptr, self.pred = _csr(self.n_vertices, [(h, t) for t, h in edges + type1])
        self.succ_ptr, self.succ = _csr(self.n_vertices, [(t, h) for t, h in edges + type1])
        # Every edge goes to a higher level, so (level, robot) is a topological order.
        self.order: list[int] = sorted(
            range(self.n_vertices), key=lambda v: (level[v], self.robot_of[v])
        )
        self.topo: list[int] = [0] * self.n_vertices
        for rank, v in enumerate(self.order):
            self.topo[v] = rank

    def with_type2(self, edges: list[tuple[int, int]]) -> ADG:
        """The same actions ordered by other Type 2 ``edges`` (tail, head vertex ids), e.g.
        switched ones (:mod:`gateway.execution.oneshot.reschedule`); ExecutionError if the graph
        would
        have a cycle."""
        out = copy.copy(self)  # the vertex lists are shared: neither graph changes them
        nv = self.n_vertices
        indegree = [0 if self.is_first[v] else 1 for v in range(nv)]
        succ: list[list[int]] = [[] for _ in range(nv)]
        for t, h in edges:
            succ[t].append(h)
            indegree[h] += 1
        for v in range(nv - 1):
            if not self.is_first[v + 1]:
                succ[v].append(v + 1)
        level = [0] * nv
        ready = [v for v in range(nv) if indegree[v] == 0]
        seen = 0
        while ready:
            v = ready.pop()
            seen += 1
            for w in succ[v]:
                if level[w] <= level[v]:
                    level[w] = level[v] + 1
                indegree[w] -= 1
                if indegree[w] == 0:
                    ready.append(w)
        if seen < nv:
            raise ExecutionError("the Type 2 edges make a cycle: the robots would wait for "
                                 "each other forever")
        out._set_edges(list(edges), level)
        return out

    def type2_pairs(self) -> list[tuple[int, int]]:
        """Every Type 2 edge as (tail, head) vertex ids, by tail."""
        return [(v, w) for v in range(self.n_vertices)
                for w in self.t2_succ[self.t2_succ_ptr[v]:self.t2_succ_ptr[v + 1]]]

    def _type2_edges(self) -> list[tuple[int, int]]:
        """(tail, head) for every move leaving u and the first later entry of each other robot.

        Per cell, each robot's entering actions are kept sorted by path index (they are built
        in path order), so each lookup is a bisection: O(actions x robots-per-cell x log).
        """
        entering: dict[Cell, dict[int, tuple[list[int], list[int]]]] = {}
        for v in range(self.n_vertices):
            if self.src[v] != self.dst[v]:
                per_robot = entering.setdefault(self.dst[v], {})
                steps, vertices = per_robot.setdefault(self.robot_of[v], ([], []))
                steps.append(self.step_of[v])
                vertices.append(v)
        edges: list[tuple[int, int]] = []
        for v in range(self.n_vertices):
            u = self.src[v]
            if u == self.dst[v] or u not in entering:
                continue
            k, i = self.robot_of[v], self.step_of[v]
            for k2, (steps, vertices) in entering[u].items():
                if k2 != k:
                    pos = bisect_right(steps, i)
                    if pos < len(steps):
                        edges.append((v, vertices[pos]))
        return edges

    def heading(self, robot: int, step: int) -> int | None:
        """Robot's heading at timestep ``step`` of the plan (None under ``omni``)."""
        if self.headings is None:
            return None
        hs = self.headings[robot]
        return hs[min(step, len(hs) - 1)]

    def n_actions(self, robot: int) -> int:
        """Number of actions in the robot's path (waits included even if dropped)."""
        return self._action_first[robot + 1] - self._action_first[robot]

    def vertex(self, robot: int, action: int) -> int:
        """Vertex id of ``a_action^robot``; ExecutionError if it does not exist."""
        if not 0 <= robot < self.n_robots:
            raise ExecutionError(f"unknown robot {robot} (the plan has {self.n_robots} robots)")
        n = self.n_actions(robot)
        if not 0 <= action < n:
            raise ExecutionError(
                f"robot {robot} has no action {action} (its actions are 0..{n - 1})"
                if n else f"robot {robot} has no action {action} (its path has no actions)"
            )
        v = self._vertex_at[self._action_first[robot] + action]
        if v < 0:
            raise ExecutionError(f"action {action} of robot {robot} is a wait (waits dropped)")
        return v

    def t1_pred(self, v: int) -> int:
        """The robot's previous action's vertex, or -1 for its first action."""
        return -1 if self.is_first[v] else v - 1

    def predecessors(self, v: int) -> list[int]:
        """All vertices with an edge into ``v`` (ascending ids)."""
        return self.pred[self.pred_ptr[v] : self.pred_ptr[v + 1]]

    def successors(self, v: int) -> list[int]:
        """All vertices with an edge out of ``v`` (ascending ids)."""
        return self.succ[self.succ_ptr[v] : self.succ_ptr[v + 1]]

    def type2_edges(self) -> Iterator[tuple[int, int, int, int]]:
        """Type 2 edges as ``(robot, action, robot2, action2)``, tail first."""
        for v in range(self.n_vertices):
            for w in self.t2_succ[self.t2_succ_ptr[v] : self.t2_succ_ptr[v + 1]]:
                yield self.robot_of[v], self.step_of[v], self.robot_of[w], self.step_of[w]


def gated_waits(plan: Plan, blocked: Collection[Cell]) -> frozenset[tuple[int, int]]:
    """The waits of ``plan`` (``(robot, path index)``) that only wait for a ``blocked`` cell:
    each run of waits right before a move into such a cell (a turn ends a run). A plan solved
    with the blocks as obstacles holds a robot there until the block's expected end; without
    these waits its move starts when the block really ends, earlier or later."""
    out: set[tuple[int, int]] = set()
    if not blocked:
        return frozenset()
    for k, path in enumerate(plan.paths):
        hs = None if plan.headings is None else plan.headings[k]
        run: list[int] = []
        for i in range(len(path) - 1):
            same = path[i] == path[i + 1] and (hs is None or hs[i] == hs[i + 1])
            if same:
                run.append(i)
                continue
            if run and path[i + 1] in blocked and path[i] != path[i + 1]:
                out.update((k, j) for j in run)
            run = []
    return frozenset(out)
