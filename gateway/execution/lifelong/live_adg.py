"""An Action Dependency Graph that grows while the fleet moves (lifelong execution).

Hönig et al. (RA-L 2019, "Persistent and robust execution of MAPF schedules in warehouses")
keep one ADG for a whole shift: each new plan segment starts where the robots' committed
actions end and is appended; nothing already committed changes, and robots never stop for a
replan. This module is that graph, for flat cell ids and the ``omni`` or ``turning`` model.

Vertices are a robot's actions in order (a move, or a turn; waits get no vertex, as with
``drop_waits``), numbered per robot by a sequence number ``seq``. Type 1 edges are implicit:
a robot runs its actions in order. Type 2 edges: the visits of each cell form a chain in plan
order, so an action that enters cell u depends on the last action (in plan order, over all
segments so far) that left u, if another robot made it. That one edge orders the entry after
every earlier visit of u (the earlier visits are chained already), so the DESIGN's full set of
Type 2 edges adds nothing to safety. Edges only go from earlier to later segments or steps,
so the graph stays acyclic: no delay can deadlock or collide the fleet.

:meth:`LiveADG.append` accepts a segment only if it is a valid 1-robust step sequence from
the committed end states (legal moves, no vertex conflict, no robot entering a cell another
robot held the step before): the guarantee does not rest on the planner. Completed actions are
dropped, so memory is bounded by what is committed and not yet done.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

from gateway.execution.errors import ExecutionError
from gateway.planning.grid import Grid

FORWARD, CW, CCW = 0, 1, 2
"""Action kinds: a move to the next cell (any 4-neighbour under ``omni``), or a turn."""


@dataclass(frozen=True, slots=True)
class LiveAction:
    """One committed action: kind, resulting cell and heading, and its Type 2 dependency
    ``(robot, seq)`` (robot -1: none). ``order`` is its position in append order (a
    topological order of the graph)."""

    kind: int
    cell: int
    heading: int
    dep_robot: int
    dep_seq: int
    order: int


class LiveADG:
    """The committed, unfinished actions of every robot, with their Type 2 dependencies."""

    def __init__(self, grid: Grid, starts: Sequence[int],
                 headings: Sequence[int] | None = None) -> None:
        self.grid = grid
        n = len(starts)
        self.n_robots = n
        self.turning = headings is not None
        self.end_cell = list(starts)
        self.end_heading = list(headings) if headings is not None else [0] * n
        self.queue: list[deque[LiveAction]] = [deque() for _ in range(n)]
        self.done = [0] * n  # completed actions per robot = seq of its next action
        self.appended = [0] * n  # seq of the next appended action
        self._leaver_robot = [-1] * grid.size  # last committed action leaving each cell
        self._leaver_seq = [0] * grid.size
        self._order = 0
        if len(set(starts)) != n:
            raise ExecutionError("two robots start on the same cell")

    # ----------------------------------------------------------------- snapshot
    def snapshot(self) -> dict[str, Any]:
        """The graph's state as plain data (a shift snapshot's ADG fields): each robot's end
        pose, its committed, unfinished actions as rows, its counters, the cells' last
        leavers ``(cell, robot, seq)`` and the append order."""
        return {
            "end_cell": list(self.end_cell), "end_heading": list(self.end_heading),
            "queue": [[(a.kind, a.cell, a.heading, a.dep_robot, a.dep_seq, a.order) for a in q]
                      for q in self.queue],
            "done": list(self.done), "appended": list(self.appended),
            "leavers": [(c, r, self._leaver_seq[c]) for c, r in enumerate(self._leaver_robot)
                        if r >= 0],
            "order": self._order}

    def restore(self, *, end_cell: Sequence[int], end_heading: Sequence[int],
                queue: Sequence[Sequence[Sequence[int]]], done: Sequence[int],
                appended: Sequence[int], leavers: Sequence[Sequence[int]], order: int) -> None:
        """Take the state :meth:`snapshot` gave (of a graph on the same grid and fleet)."""
        self.end_cell, self.end_heading = list(end_cell), list(end_heading)
        self.queue = [deque(LiveAction(*row) for row in q) for q in queue]
        self.done, self.appended = list(done), list(appended)
        self._leaver_robot = [-1] * self.grid.size
        self._leaver_seq = [0] * self.grid.size
        for c, r, s in leavers:
            self._leaver_robot[c], self._leaver_seq[c] = r, s
        self._order = order

    # ----------------------------------------------------------------- building
    def append(self, cells: Sequence[Sequence[int]],
               headings: Sequence[Sequence[int]] | None = None) -> None:
        """Append a plan segment: ``cells[j][r]`` (and ``headings[j][r]`` under ``turning``)
        is robot r's state at step j, step 0 being the committed end states.

        Raises ExecutionError (and changes nothing) unless every step is a legal action and
        the segment is 1-robust.
        """
        n = self.n_robots
        if not cells or any(len(row) != n for row in cells):
            raise ExecutionError(f"a segment needs {n} cells per step")
        if list(cells[0]) != self.end_cell:
            raise ExecutionError("the segment does not start at the committed end states")
        if self.turning:
            if headings is None or len(headings) != len(cells) or any(
                    len(row) != n for row in headings):
                raise ExecutionError("a turning segment needs a heading per robot and step")
            if list(headings[0]) != self.end_heading:
                raise ExecutionError("the segment does not start at the committed headings")
        self._check(cells, headings)
        leaver_r, leaver_s = self._leaver_robot, self._leaver_seq
        seq = self.appended
        for j in range(1, len(cells)):
            prev, cur = cells[j - 1], cells[j]
            hprev = headings[j - 1] if headings is not None else None
            hcur = headings[j] if headings is not None else None
            for r in range(n):
                u, v = prev[r], cur[r]
                if u != v:
                    dr = leaver_r[v]
                    if dr == r or dr < 0:
                        dep_r, dep_s = -1, 0
                    else:
                        dep_r, dep_s = dr, leaver_s[v]
                    h = hcur[r] if hcur is not None else 0
                    self.queue[r].append(LiveAction(FORWARD, v, h, dep_r, dep_s, self._order))
                    leaver_r[u], leaver_s[u] = r, seq[r]
                elif hcur is not None and hprev is not None and hcur[r] != hprev[r]:
                    kind = CW if (hcur[r] - hprev[r]) % 4 == 1 else CCW
                    self.queue[r].append(LiveAction(kind, v, hcur[r], -1, 0, self._order))
                else:
                    continue
                seq[r] += 1
                self._order += 1
        self.end_cell = list(cells[-1])
        if headings is not None:
            self.end_heading = list(headings[-1])

    def _check(self, cells: Sequence[Sequence[int]],
               headings: Sequence[Sequence[int]] | None) -> None:
        """Legal actions, no vertex conflict, 1-robust (see :meth:`append`)."""
        free_flat = self.grid.free.ravel()
        n, width = self.n_robots, self.grid.width
        for j in range(1, len(cells)):
            prev, cur = cells[j - 1], cells[j]
            if len(set(cur)) != n:
                raise ExecutionError(f"vertex conflict at step {j} of the segment")
            held = set(prev)
            for r in range(n):
                u, v = prev[r], cur[r]
                if u == v:
                    if headings is not None and (headings[j][r] - headings[j - 1][r]) % 4 == 2:
                        raise ExecutionError(f"robot {r} turns 180 degrees at step {j}")
                    continue
                if not 0 <= v < len(free_flat) or not free_flat[v]:
                    raise ExecutionError(f"robot {r} enters a blocked cell at step {j}")
                d = v - u
                if not ((d in (1, -1) and v // width == u // width) or d in (width, -width)):
                    raise ExecutionError(f"robot {r} jumps from {u} to {v} at step {j}")
                if headings is not None:
                    h = headings[j - 1][r]
                    if headings[j][r] != h or d != (1, width, -1, -width)[h]:
                        raise ExecutionError(f"robot {r} moves off its heading at step {j}")
                if v in held:
                    raise ExecutionError(
                        f"robot {r} enters cell {v} at step {j}, held by another robot the step "
                        "before (the segment is not 1-robust)")

    def retract(self, keep: Sequence[int], cells: Sequence[int],
                headings: Sequence[int] | None = None) -> list[int]:
        """Take back committed actions that have not started, so the next segment plans those
        robots anew from where they will be: robot r keeps at most its first ``keep[r]``
        pending actions (its started one must be among them), fewer where a kept action
        depends on one taken back, so no dependency is broken and the graph stays acyclic and
        safe. ``cells[r]`` / ``headings[r]``: where robot r stands after its finished actions
        (its end state if it keeps none). Returns how many actions each robot keeps."""
        n, done, queue = self.n_robots, self.done, self.queue
        k = [min(max(0, keep[r]), len(queue[r])) for r in range(n)]
        cut = [r for r in range(n) if k[r] < len(queue[r])]
        if not cut:
            return k
        changed = True
        while changed:  # a kept action waiting on one taken back is taken back too
            changed = False
            for r in range(n):
                q = queue[r]
                for i in range(k[r]):
                    a = q[i]
                    if a.dep_robot >= 0 and a.dep_seq >= done[a.dep_robot] + k[a.dep_robot]:
                        if k[r] == len(q):
                            cut.append(r)
                        k[r] = i
                        changed = True
                        break
        leaver_r, leaver_s = self._leaver_robot, self._leaver_seq
        stale: set[int] = set()  # cells whose last leaver is taken back
        for r in cut:
            q = queue[r]
            prev = q[k[r] - 1].cell if k[r] else cells[r]
            for i in range(k[r], len(q)):
                a = q[i]
                if a.kind == FORWARD:
                    if leaver_r[prev] == r and leaver_s[prev] == done[r] + i:
                        stale.add(prev)
                        leaver_r[prev] = -1
                    prev = a.cell
            while len(q) > k[r]:
                q.pop()
            self.appended[r] = done[r] + k[r]
            if q:
                self.end_cell[r], self.end_heading[r] = q[-1].cell, q[-1].heading
            else:
                self.end_cell[r] = cells[r]
                self.end_heading[r] = headings[r] if headings is not None else 0
        if stale:  # their last kept leaver, if any (a finished one orders nothing any more)
            kept = []
            for r in range(n):
                prev = cells[r]
                for i, a in enumerate(queue[r]):
                    if a.kind == FORWARD:
                        if prev in stale:
                            kept.append((a.order, r, done[r] + i, prev))
                        prev = a.cell
            for _, r, seq, cell in sorted(kept):
                leaver_r[cell], leaver_s[cell] = r, seq
        return k

    # ----------------------------------------------------------------- execution
    def head(self, robot: int) -> LiveAction | None:
        """The robot's next committed action, or None."""
        q = self.queue[robot]
        return q[0] if q else None

    def is_ready(self, robot: int) -> bool:
        """True if the robot has a next action and its Type 2 dependency is done."""
        q = self.queue[robot]
        if not q:
            return False
        a = q[0]
        return a.dep_robot < 0 or self.done[a.dep_robot] > a.dep_seq

    def finish(self, robot: int) -> LiveAction:
        """The robot's next action is done: drop it and return it."""
        q = self.queue[robot]
        if not q:
            raise ExecutionError(f"robot {robot} has no committed action to finish")
        self.done[robot] += 1
        return q.popleft()

    def pending(self, robot: int) -> int:
        """Number of the robot's committed, unfinished actions."""
        return len(self.queue[robot])

    def n_pending(self) -> int:
        """Committed, unfinished actions of the whole fleet (the graph's size)."""
        return sum(len(q) for q in self.queue)

    def estimate(self, now: float, progress: Sequence[float], durations: Sequence[float],
                 blocked_until: Sequence[float] | None = None) -> list[list[float]]:
        """Algorithm 1 over the committed actions: per robot, the estimated completion time of
        each pending action (same order as its queue).

        ``durations[kind]`` is an action's duration; ``progress[r]`` how much of robot r's
        head action is already done (0 if it has not started); ``blocked_until[r]`` the
        earliest time robot r can act (a known delay). Append order is topological, so one
        pass in that order is exact; a done dependency counts as finished before ``now``.
        """
        n = self.n_robots
        out: list[list[float]] = [[] for _ in range(n)]
        items = sorted((a.order, r, i) for r in range(n) for i, a in enumerate(self.queue[r]))
        for _, r, i in items:
            a = self.queue[r][i]
            start = now if blocked_until is None else max(now, blocked_until[r])
            if i > 0:
                start = max(start, out[r][i - 1])
            if a.dep_robot >= 0 and self.done[a.dep_robot] <= a.dep_seq:
                start = max(start, out[a.dep_robot][a.dep_seq - self.done[a.dep_robot]])
            left = durations[a.kind] - (progress[r] if i == 0 else 0.0)
            out[r].append(start + left)
        return out
