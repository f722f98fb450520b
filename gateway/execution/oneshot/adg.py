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
from collections.abc import Collection, Iterator, Sequence

import numpy as np
import numpy.typing as npt

from gateway.execution.actions import ActionKind, action_kind
from gateway.execution.errors import ExecutionError
from gateway.planning.grid import Cell
from gateway.planning.plan import Plan


def _csr(n: int, keys: npt.NDArray[np.int64],
         values: npt.NDArray[np.int64]) -> tuple[list[int], list[int]]:
    """Pointer and index lists of the pairs (``keys[i]``, ``values[i]``) grouped by key,
    values sorted."""
    order = np.lexsort((values, keys))
    ptr = np.zeros(n + 1, dtype=np.int64)
    np.cumsum(np.bincount(keys, minlength=n), out=ptr[1:])
    return ptr.tolist(), values[order].tolist()


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

    def _set_edges(self, edges: Sequence[tuple[int, int]] | npt.NDArray[np.int64],
                   level: list[int]) -> None:
        """Install the Type 2 ``edges`` (tail, head) and the Type 1 chain, with ``level``: a
        number per vertex that grows along every edge (the topological order's key)."""
        self.level = level
        """Grows along every edge: the plan step, or (rescheduled) the longest path from a
        source; :class:`~gateway.execution.oneshot.monitor.Monitor` evaluates vertices by level."""
        pairs = np.array(edges, dtype=np.int64).reshape(-1, 2)
        tails, heads = pairs[:, 0], pairs[:, 1]
        n = self.n_vertices
        self.t2_pred_ptr, self.t2_pred = _csr(n, heads, tails)
        self.t2_succ_ptr, self.t2_succ = _csr(n, tails, heads)
        # all edges (Type 1 and 2) in CSR form, for the monitor's inner loop
        chained = np.flatnonzero(np.frombuffer(self.is_first, dtype=np.uint8) == 0)
        all_tails = np.concatenate((tails, chained - 1))
        all_heads = np.concatenate((heads, chained))
        self.pred_ptr, self.pred = _csr(n, all_heads, all_tails)
        self.succ_ptr, self.succ = _csr(n, all_tails, all_heads)
        # Every edge goes to a higher level, so (level, robot) is a topological order (ties:
        # by vertex id, a stable sort).
        order = np.lexsort((np.asarray(self.robot_of, dtype=np.int64),
                            np.asarray(level, dtype=np.int64)))
        topo = np.empty(n, dtype=np.int64)
        topo[order] = np.arange(n, dtype=np.int64)
        self.order: list[int] = order.tolist()
        self.topo: list[int] = topo.tolist()

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

    def _type2_edges(self) -> npt.NDArray[np.int64]:
        """(tail, head) for every move leaving u and the first later entry of each other robot,
        ordered by tail, then head.

        Vectorised: the moves entering each cell are grouped by (cell, robot) and sorted by
        path index; every move leaving a cell is paired with each other robot's group of that
        cell, and one binary search over all groups at once finds that robot's first entry
        after it. O(pairs x log(actions)) in numpy, no loop per action.
        """
        n = self.n_vertices
        none = np.zeros((0, 2), dtype=np.int64)
        if n == 0:
            return none
        src = np.asarray(self.src, dtype=np.int64).reshape(n, 2)
        dst = np.asarray(self.dst, dtype=np.int64).reshape(n, 2)
        robot = np.asarray(self.robot_of, dtype=np.int64)
        step = np.asarray(self.step_of, dtype=np.int64)
        width = int(max(src[:, 1].max(), dst[:, 1].max())) + 1
        moves = np.flatnonzero((src != dst).any(axis=1))
        if len(moves) == 0:
            return none
        into = dst[moves, 0] * width + dst[moves, 1]  # the cell each move enters
        # entries sorted by (cell, robot, step): groups of one robot entering one cell
        e_order = np.lexsort((step[moves], robot[moves], into))
        e_vertex, e_cell = moves[e_order], into[e_order]
        e_robot, e_step = robot[e_vertex], step[e_vertex]
        new_group = np.ones(len(e_vertex), dtype=bool)
        new_group[1:] = (e_cell[1:] != e_cell[:-1]) | (e_robot[1:] != e_robot[:-1])
        g_start = np.flatnonzero(new_group)  # each group's first entry
        g_of_entry = np.cumsum(new_group) - 1
        g_cell, g_robot = e_cell[g_start], e_robot[g_start]
        # each cell's groups are a contiguous range of groups
        cells, c_first, c_count = np.unique(g_cell, return_index=True, return_counts=True)
        # queries: every move, leaving its source cell; keep those whose cell is entered
        out_cell = src[moves, 0] * width + src[moves, 1]
        pos = np.searchsorted(cells, out_cell)
        pos_ok = np.minimum(pos, len(cells) - 1)
        hit = cells[pos_ok] == out_cell
        q_vertex, q_cell_idx = moves[hit], pos_ok[hit]
        counts = c_count[q_cell_idx]
        # one (query, group) pair per robot entering the query's cell
        pair_q = np.repeat(np.arange(len(q_vertex)), counts)
        offsets = np.arange(len(pair_q)) - np.repeat(np.cumsum(counts) - counts, counts)
        pair_g = c_first[q_cell_idx][pair_q] + offsets
        tail = q_vertex[pair_q]
        other = g_robot[pair_g] != robot[tail]
        tail, pair_g = tail[other], pair_g[other]
        # the group's first entry with a larger path index than the tail's
        key = g_of_entry * (int(step.max()) + 2) + e_step
        found = np.searchsorted(key, pair_g * (int(step.max()) + 2) + step[tail], side="right")
        found_ok = np.minimum(found, len(key) - 1)
        later = (found < len(key)) & (g_of_entry[found_ok] == pair_g)
        tail, head = tail[later], e_vertex[found_ok[later]]
        ordered = np.lexsort((head, tail))
        return np.stack((tail[ordered], head[ordered]), axis=1)

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
