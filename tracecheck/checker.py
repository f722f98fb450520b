"""An independent checker of execution traces (DESIGN section 3).

It uses nothing of the executor, the monitor or the simulated world: from the records alone it
re-derives each adopted plan's action dependency graph (Type 1 and Type 2 edges as DESIGN
section 2 defines them), replays the events in order and reports

* an action that started before all its ADG predecessors had finished (or without dispatch),
  or was dispatched before its Type 2 predecessors finished and its robot's previous action
  was dispatched (lookahead dispatch may queue an action behind the robot's current one),
* two robots, or a robot and the intruder, on one cell at once (a moving robot holds both
  its cells),
* under the ``turning`` motion model (plan records with ``"motion": "turning"`` and path
  entries ``[x, y, heading]``, heading 0 east (+x), 1 south (+y), 2 west, 3 north): a step
  that is no legal action (a turn of other than 90 degrees, a move that is not one cell
  forward along the held heading or that also turns), and a new plan whose start headings are
  not the robots' headings; a turn holds its cell, so it enters none,
* an action of the final plan that did not run exactly once, or any started action that never
  finished, and a new plan that does not start where the robots stand,
* a summary whose SOC or makespan differs from the finish times in the trace,
* lifelong runs (a ``plan`` record with ``"lifelong": true`` whose paths are the start poses,
  then ``segment`` records that extend every robot's path step by step, each from where the
  previous one ended): waits are no actions there, so an event's ``action`` is the robot's
  n-th change of pose over the run; the ADG is re-derived over the concatenated paths with the
  same Type 2 rule (timesteps counted across segments), actions committed but not run when
  the trace ends are no error, and the slack at a ``trigger`` is not recomputed,
* a ``reschedule`` record (the plan's Type 2 edges replaced by switched ones) that gives an
  action already dispatched a new predecessor or makes the graph cyclic; from then on the
  new edges are the plan's (and its Δ0 stays the one of the plan as adopted),

and it recomputes the fleet slack (Algorithm 1 plus DESIGN's slack definitions) at any moment,
in particular at every ``trigger`` record; an agent's ``durations_ms`` (``{"move", "turn",
"wait"}``, each 1000 ms if absent) are its actions' expected durations ``t_x``, and its
``skip`` lists the path indices of waits that are no actions (an informed replan's waits
for a blocked cell: the robot moves in when the cell is free). Run it as
``python -m tracecheck FILE``.
"""

from __future__ import annotations

import math
import sys
from bisect import bisect_right
from collections.abc import Collection, Iterable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

from fleetgate.userio.exits import EPILOG, CommandParser, UsageError, call
from tracecheck.reader import read_trace

Pos = tuple[int, int]
Act = tuple[int, int]
"""``(robot, action index)``."""

ACTION_MS = 1000.0
TOLERANCE_MS = 1e-6
FORWARD: tuple[Pos, ...] = ((1, 0), (0, 1), (-1, 0), (0, -1))
"""The cell offset of one step forward for headings 0..3."""


def step_kind(src: Pos, dst: Pos, h0: int | None, h1: int | None) -> str:
    """"move", "turn" or "wait"; "illegal: <why>" for anything else."""
    dx, dy = dst[0] - src[0], dst[1] - src[1]
    if h0 is None or h1 is None:
        if abs(dx) + abs(dy) > 1:
            return f"illegal: {src} -> {dst} is no 4-neighbour step"
        return "wait" if src == dst else "move"
    if not (0 <= h0 <= 3 and 0 <= h1 <= 3):
        return f"illegal: heading {h0} -> {h1} outside 0..3"
    if src == dst:
        if h0 == h1:
            return "wait"
        return "turn" if (h1 - h0) % 4 in (1, 3) else \
            f"illegal: turn {h0} -> {h1} on {src} is not 90 degrees"
    if h0 != h1:
        return f"illegal: move {src} -> {dst} turns from {h0} to {h1}"
    if (dx, dy) != FORWARD[h0]:
        return f"illegal: move {src} -> {dst} is not one cell forward along heading {h0}"
    return "move"


@dataclass(frozen=True, slots=True)
class SeenCollision:
    """At ``t_ms`` ``who`` (a robot id or "intruder") entered ``cell`` held by ``holders``."""

    t_ms: float
    cell: Pos
    who: str
    holders: tuple[str, ...]


@dataclass
class PlanGraph:
    """One adopted plan: its paths (and headings, turning), release time, re-derived ADG, and
    each action's kind and expected duration."""

    plan: int
    release_ms: float
    paths: list[list[Pos]]
    preds: dict[Act, list[Act]]
    type2_in: dict[Act, list[Act]]
    headings: list[list[int]] | None = None
    kinds: dict[Act, str] = field(default_factory=dict)
    tx: dict[Act, float] = field(default_factory=dict)
    topo: list[Act] | None = None
    """A topological order once rescheduled (switched Type 2 edges need not go forward)."""
    lifelong: LifelongSteps | None = None

    def actions(self) -> Iterable[Act]:
        """Every action in a topological order of the ADG: by index then robot, unless
        rescheduled."""
        if self.topo is not None:
            yield from self.topo
            return
        longest = max((len(p) for p in self.paths), default=1)
        for i in range(longest - 1):
            for k, path in enumerate(self.paths):
                if i < len(path) - 1 and (k, i) in self.preds:
                    yield k, i


def build_graph(plan: int, release_ms: float, paths: Sequence[Sequence[Pos]],
                headings: Sequence[Sequence[int]] | None = None,
                durations: Sequence[Mapping[str, float]] | None = None,
                skips: Sequence[Collection[int]] | None = None) -> PlanGraph:
    """The ADG of ``paths``: a_i^k -> a_{i+1}^k, and from every action leaving a cell u to
    each other robot's first later action (j > i) entering u (a turn leaves and enters
    nothing). ``durations[k]`` maps robot k's action kinds to t_x (1000 ms if absent).
    ``skips[k]`` are path indices of robot k's waits that are no actions (a robot that
    waits for a blocked cell moves in when it is free): they get no vertex, and the robot's
    next action follows its previous one directly (a wait enters no cell, so no Type 2
    edge changes); a skipped step that is no wait is kept, with the kind ``illegal``."""
    plist = [list(p) for p in paths]
    hlist = None if headings is None else [list(h) for h in headings]
    preds: dict[Act, list[Act]] = {}
    type2_in: dict[Act, list[Act]] = {}
    kinds: dict[Act, str] = {}
    tx: dict[Act, float] = {}
    enters: dict[Pos, dict[int, list[int]]] = {}
    for k, path in enumerate(plist):
        hs = None if hlist is None else hlist[k]
        skip = set(skips[k]) if skips is not None and k < len(skips) else set()
        prev = -1
        for i in range(len(path) - 1):
            kind = step_kind(path[i], path[i + 1], None if hs is None else hs[i],
                             None if hs is None else hs[i + 1])
            if i in skip:
                if kind == "wait":
                    continue
                kind = f"illegal: step {i} is skipped but is no wait"
            preds[(k, i)] = [(k, prev)] if prev >= 0 else []
            type2_in[(k, i)] = []
            prev = i
            kinds[(k, i)] = kind
            model = durations[k] if durations is not None else {}
            tx[(k, i)] = float(model.get(kind, ACTION_MS))
            if path[i] != path[i + 1]:
                enters.setdefault(path[i + 1], {}).setdefault(k, []).append(i)
    for k, path in enumerate(plist):
        for i in range(len(path) - 1):
            u = path[i]
            if u == path[i + 1]:
                continue
            for k2, js in enters.get(u, {}).items():
                if k2 == k:
                    continue
                pos = bisect_right(js, i)
                if pos < len(js):
                    head = (k2, js[pos])
                    preds[head].append((k, i))
                    type2_in[head].append((k, i))
    return PlanGraph(plan, release_ms, plist, preds, type2_in, hlist, kinds, tx)


@dataclass
class LifelongSteps:
    """A lifelong plan's timestep bookkeeping: the global timestep so far, and per cell the
    moves that left it ``(timestep, robot, action)`` and each robot's last entry into it."""

    step: int = 0
    leaves: dict[Pos, list[tuple[int, int, int]]] = field(default_factory=dict)
    last_entry: dict[tuple[Pos, int], int] = field(default_factory=dict)


def extend_graph(graph: PlanGraph, paths: Sequence[Sequence[Pos]],
                 headings: Sequence[Sequence[int]] | None,
                 durations: Sequence[Mapping[str, float]]) -> list[str]:
    """Append a lifelong segment (every robot's poses step by step, from where its path ends)
    to ``graph``: each change of pose is an action; an action entering cell u depends on its
    robot's previous action and on every other robot's move out of u made at an earlier
    timestep and after this robot's previous entry into u (DESIGN's Type 2 rule). Returns
    what is wrong with the segment."""
    steps = graph.lifelong
    assert steps is not None
    errors: list[str] = []
    length = len(paths[0]) if paths else 0
    for k, path in enumerate(paths):
        if len(path) != length:
            errors.append(f"robot {k}'s segment has {len(path)} steps, robot 0's {length}")
            return errors
        hs = None if headings is None or graph.headings is None else headings[k]
        end_h = None if graph.headings is None else graph.headings[k][-1]
        if path[0] != graph.paths[k][-1] or (hs is not None and hs[0] != end_h):
            errors.append(f"robot {k}'s segment starts at {path[0]}, its plan ends at "
                          f"{graph.paths[k][-1]}")
            return errors
    for j in range(1, length):
        t = steps.step + j
        for k, path in enumerate(paths):
            hs = None if headings is None else headings[k]
            h0, h1 = (None, None) if hs is None else (hs[j - 1], hs[j])
            src, dst = path[j - 1], path[j]
            kind = step_kind(src, dst, h0, h1)
            if kind == "wait":
                continue
            if kind.startswith("illegal"):
                errors.append(f"robot {k} step {t}: {kind[len('illegal: '):]}")
                continue
            i = len(graph.paths[k]) - 1
            a = (k, i)
            graph.paths[k].append(dst)
            if graph.headings is not None and h1 is not None:
                graph.headings[k].append(h1)
            graph.kinds[a] = kind
            graph.tx[a] = float(durations[k].get(kind, ACTION_MS)) if k < len(durations) \
                else ACTION_MS
            graph.preds[a] = [(k, i - 1)] if i > 0 else []
            graph.type2_in[a] = []
            if src == dst:
                continue
            since = steps.last_entry.get((dst, k), -1)
            for t_leave, k2, i2 in steps.leaves.get(dst, []):
                if k2 != k and since < t_leave < t:
                    graph.preds[a].append((k2, i2))
                    graph.type2_in[a].append((k2, i2))
            steps.last_entry[(dst, k)] = t
            steps.leaves.setdefault(src, []).append((t, k, i))
    steps.step += max(0, length - 1)
    return errors


@dataclass
class ExecState:
    """What happened to one plan's actions so far (real start and finish times)."""

    graph: PlanGraph
    dispatched: set[Act] = field(default_factory=set)
    cancelled: set[Act] = field(default_factory=set)
    started: dict[Act, float] = field(default_factory=dict)
    finished: dict[Act, float] = field(default_factory=dict)
    delta0: dict[Act, float] | None = None
    """Δ0 of the plan as adopted, kept when it is rescheduled (None: not rescheduled)."""


def _topological(preds: Mapping[Act, Sequence[Act]]) -> list[Act] | None:
    """The actions in an order where each comes after its predecessors (None: a cycle)."""
    left = {a: len(ps) for a, ps in preds.items()}
    succ: dict[Act, list[Act]] = {a: [] for a in preds}
    for a, ps in preds.items():
        for p in ps:
            succ[p].append(a)
    ready = [a for a, n in left.items() if n == 0]
    out: list[Act] = []
    while ready:
        a = ready.pop()
        out.append(a)
        for b in succ[a]:
            left[b] -= 1
            if left[b] == 0:
                ready.append(b)
    return out if len(out) == len(preds) else None


def estimates(state: ExecState,
              now_ms: float | None) -> tuple[dict[Act, float], dict[Act, float]]:
    """Algorithm 1 with real times and the present as a lower bound (``now_ms`` None: the
    initial estimate), each action taking its own t_x. Returns ``(t_s, t_c)``."""
    g = state.graph
    ts: dict[Act, float] = {}
    tc: dict[Act, float] = {}
    for a in g.actions():
        if a in state.finished:
            ts[a] = state.started[a]
            tc[a] = state.finished[a]
        elif a in state.started:
            ts[a] = state.started[a]
            tc[a] = ts[a] + g.tx[a] if now_ms is None else max(ts[a] + g.tx[a], now_ms)
        else:
            preds = g.preds[a]
            start = max((tc[p] for p in preds), default=g.release_ms)
            if now_ms is not None and all(p in state.finished for p in preds):
                start = max(start, now_ms)
            ts[a] = start
            tc[a] = start + g.tx[a]
    return ts, tc


def action_slacks(graph: PlanGraph, tc: Mapping[Act, float]) -> dict[Act, float]:
    """Δ(a) = max(0, max over incoming Type 2 edges of t_c(tail) - t_c(a_{j-1}))."""
    out: dict[Act, float] = {}
    for (k, j), tails in graph.type2_in.items():
        own = [p for p in graph.preds[(k, j)] if p[0] == k]
        before = tc[own[0]] if own else graph.release_ms
        out[(k, j)] = max([0.0, *(tc[t] - before for t in tails)])
    return out


def fleet_slack(state: ExecState, now_ms: float) -> float:
    """Δ̄F at ``now_ms``: the largest growth of Δ over the initial estimate among the actions
    not started yet (0 if every action started)."""
    g = state.graph
    initial = state.delta0 if state.delta0 is not None else \
        action_slacks(g, estimates(ExecState(g), None)[1])
    current = action_slacks(g, estimates(state, now_ms)[1])
    return max((current[a] - initial[a] for a in current if a not in state.started), default=0.0)


@dataclass
class TraceReport:
    """The checker's findings; :attr:`ok` is True when there is nothing to complain about."""

    errors: list[str] = field(default_factory=list)
    collisions: list[SeenCollision] = field(default_factory=list)
    plans: int = 0
    actions_run: int = 0
    soc_ms: float = 0.0
    makespan_ms: float = 0.0
    triggers: list[tuple[float, float, float]] = field(default_factory=list)
    """``(t_ms, fleet_slack_ms recorded, fleet slack recomputed)`` per trigger."""

    @property
    def ok(self) -> bool:
        """No error and no collision."""
        return not self.errors and not self.collisions


def _who(occupant: int | str) -> str:
    return occupant if isinstance(occupant, str) else f"robot {occupant}"


class _Replay:
    """Replays records in order, keeping occupancy and per-plan execution state."""

    def __init__(self) -> None:
        self.report = TraceReport()
        self.states: list[ExecState] = []
        self.cells: dict[Pos, list[int | str]] = {}
        self.pos: list[Pos] = []
        self.heading: list[int] | None = None
        self.running: dict[int, Act] = {}
        self.last_finish: dict[int, float] = {}
        self.intruder: Pos | None = None
        self.now = 0.0
        self.summary: Mapping[str, Any] | None = None
        self.durations: list[Mapping[str, float]] = []

    def error(self, where: str, msg: str) -> None:
        self.report.errors.append(f"{where}: {msg}")

    def enter(self, cell: Pos, who: int | str, t: float) -> None:
        holders = self.cells.setdefault(cell, [])
        if holders:
            self.report.collisions.append(
                SeenCollision(t, cell, _who(who), tuple(_who(h) for h in holders)))
        holders.append(who)

    def leave(self, cell: Pos, who: int | str) -> None:
        holders = self.cells.get(cell, [])
        if who in holders:
            holders.remove(who)
        if not holders:
            self.cells.pop(cell, None)

    def record(self, n: int, rec: Mapping[str, Any]) -> None:
        where = f"record {n}"
        kind = rec.get("type")
        if self.summary is not None:
            self.error(where, "record after the summary")
        if kind == "summary":
            self.summary = rec
            return
        t = float(rec["t_ms"])
        if t < self.now - TOLERANCE_MS:
            self.error(where, f"time goes back from {self.now} to {t}")
        self.now = max(self.now, t)
        if kind == "plan":
            self.plan(where, t, rec)
        elif kind == "segment":
            self.segment(where, rec)
        elif kind in ("dispatch", "start", "finish", "blocked", "unblocked", "cancel",
                      "refused"):
            self.event(where, t, str(kind), rec)
        elif kind == "intruder":
            cell = (int(rec["cell"][0]), int(rec["cell"][1]))
            if rec["state"] == "on":
                if self.intruder is not None:
                    self.error(where, "the intruder entered a second cell")
                self.intruder = cell
                self.enter(cell, "intruder", t)
            else:
                if self.intruder != cell:
                    self.error(where, f"the intruder left {cell} where it was not")
                self.intruder = None
                self.leave(cell, "intruder")
        elif kind == "reschedule":
            self.reschedule(where, rec)
        elif kind == "trigger":
            if self.states and self.states[-1].graph.lifelong is not None:
                recomputed = math.nan  # lifelong: not recomputed (see the module doc)
            else:
                recomputed = fleet_slack(self.states[-1], t) if self.states else 0.0
            self.report.triggers.append((t, float(rec["fleet_slack_ms"]), recomputed))
        else:
            self.error(where, f"unknown record type {kind!r}")

    def plan(self, where: str, t: float, rec: Mapping[str, Any]) -> None:
        number = int(rec["plan"])
        if number != len(self.states):
            self.error(where, f"plan {number} adopted, expected plan {len(self.states)}")
        turning = rec.get("motion", "omni") == "turning"
        if rec.get("motion", "omni") not in ("omni", "turning"):
            self.error(where, f"unknown motion model {rec['motion']!r}")
        width = 3 if turning else 2
        bad = [k for k, a in enumerate(rec["agents"]) if any(len(c) != width for c in a["path"])]
        if bad:
            self.error(where, f"agents {bad}: path entries must be "
                       f"{'[x, y, heading]' if turning else '[x, y]'}")
            return
        paths = [[(int(c[0]), int(c[1])) for c in a["path"]] for a in rec["agents"]]
        headings = [[int(c[2]) for c in a["path"]] for a in rec["agents"]] if turning else None
        if (headings is None) != (self.heading is None) and self.states:
            self.error(where, "the motion model changed between plans")
        if self.states:
            if len(paths) != len(self.pos):
                self.error(where, f"plan has {len(paths)} robots, the fleet {len(self.pos)}")
            if self.running:
                self.error(where, f"plan adopted while robots {sorted(self.running)} move")
            for k, path in enumerate(paths[: len(self.pos)]):
                if path and path[0] != self.pos[k]:
                    self.error(where, f"robot {k} starts at {path[0]} but stands on "
                               f"{self.pos[k]}")
                if headings is not None and self.heading is not None and \
                        headings[k][0] != self.heading[k]:
                    self.error(where, f"robot {k} starts with heading {headings[k][0]} but "
                               f"holds {self.heading[k]}")
        else:
            self.pos = [p[0] for p in paths]
            for k, cell in enumerate(self.pos):
                self.enter(cell, k, t)
        self.heading = None if headings is None else [h[0] for h in headings]
        durations = [a.get("durations_ms", {}) for a in rec["agents"]]
        skips = [[int(i) for i in a.get("skip", [])] for a in rec["agents"]]
        graph = build_graph(number, t, paths, headings, durations, skips)
        if rec.get("lifelong"):
            graph.lifelong = LifelongSteps()
            self.durations = durations
        for (k, i), kind in graph.kinds.items():
            if kind.startswith("illegal"):
                self.error(where, f"robot {k} action {i}: {kind[len('illegal: '):]}")
        self.states.append(ExecState(graph))

    def segment(self, where: str, rec: Mapping[str, Any]) -> None:
        """A lifelong plan grows by a segment."""
        if not self.states or self.states[-1].graph.lifelong is None:
            self.error(where, "a segment without a lifelong plan")
            return
        graph = self.states[-1].graph
        turning = graph.headings is not None
        paths = [[(int(c[0]), int(c[1])) for c in a["path"]] for a in rec["agents"]]
        headings = [[int(c[2]) for c in a["path"]] for a in rec["agents"]] if turning else None
        if len(paths) != len(graph.paths):
            self.error(where, f"segment has {len(paths)} robots, the plan {len(graph.paths)}")
            return
        for err in extend_graph(graph, paths, headings, self.durations):
            self.error(where, err)

    def reschedule(self, where: str, rec: Mapping[str, Any]) -> None:
        """The plan's Type 2 edges are replaced: only actions not dispatched (or taken back)
        may gain a predecessor, and the graph must stay acyclic."""
        number = int(rec["plan"])
        if not self.states or number != len(self.states) - 1:
            self.error(where, f"reschedule of plan {number}, the current plan is "
                       f"{len(self.states) - 1}")
            return
        st = self.states[-1]
        g = st.graph
        type2_in: dict[Act, list[Act]] = {a: [] for a in g.preds}
        for e in rec["edges"]:
            tail, head = (int(e[0]), int(e[1])), (int(e[2]), int(e[3]))
            if tail not in type2_in or head not in type2_in or tail[0] == head[0]:
                self.error(where, f"no Type 2 edge can go from {tail} to {head}")
                return
            type2_in[head].append(tail)
        for a, tails in type2_in.items():
            gained = set(tails) - set(g.type2_in[a])
            if gained and a in st.dispatched and a not in st.cancelled:
                self.error(where, f"action {a} gains predecessors {sorted(gained)} after its "
                           "dispatch")
        preds = {a: [p for p in g.preds[a] if p[0] == a[0]] + type2_in[a] for a in g.preds}
        topo = _topological(preds)
        if topo is None:
            self.error(where, "the rescheduled graph has a cycle")
            return
        if st.delta0 is None:
            st.delta0 = action_slacks(g, estimates(ExecState(g), None)[1])
        st.graph = replace(g, preds=preds, type2_in=type2_in, topo=topo)

    def event(self, where: str, t: float, kind: str, rec: Mapping[str, Any]) -> None:
        k, i, number = int(rec["robot"]), int(rec["action"]), int(rec["plan"])
        if not self.states or number != len(self.states) - 1:
            self.error(where, f"{kind} for plan {number}, the current plan is "
                       f"{len(self.states) - 1}")
            return
        st = self.states[-1]
        a = (k, i)
        if a not in st.graph.preds:
            self.error(where, f"plan {number} has no action {i} for robot {k}")
            return
        src, dst = st.graph.paths[k][i], st.graph.paths[k][i + 1]
        if kind == "dispatch":
            if a in st.dispatched and a not in st.cancelled:
                self.error(where, f"action {a} dispatched twice")
            st.cancelled.discard(a)
            # lookahead dispatch: the robot's own previous action (Type 1) need only be
            # dispatched (the robot runs its queue in order); Type 2 predecessors must be done
            missing = [p for p in st.graph.preds[a] if p not in st.finished and not (
                p[0] == k and p in st.dispatched and p not in st.cancelled)]
            if missing:
                self.error(where, f"action {a} dispatched before {missing} finished")
            st.dispatched.add(a)
        elif kind == "refused":
            # the robot would not execute it: taken back like a cancel, before any start
            if a not in st.dispatched or a in st.cancelled or a in st.started:
                self.error(where, f"refused action {a} that is not waiting to start")
            st.cancelled.add(a)
        elif kind in ("blocked", "unblocked", "cancel"):
            # the executor records a cancel when the robot confirms it did not move, or that
            # it went back to the source of a move stopped on the way (blocked after start)
            moving = self.running.get(k) == a and a not in st.finished
            if a not in st.dispatched or a in st.cancelled or (a in st.started and not (
                    moving and src != dst)):
                self.error(where, f"{kind} of action {a} that is not waiting to start nor a "
                           "move under way")
            if kind == "cancel":
                st.cancelled.add(a)
                if moving:
                    del self.running[k]
                    del st.started[a]
                    self.leave(dst, k)
        elif kind == "start":
            if a not in st.dispatched or a in st.cancelled:
                self.error(where, f"action {a} started without (a standing) dispatch")
            if a in st.started:
                self.error(where, f"action {a} started twice")
                return
            missing = [p for p in st.graph.preds[a] if p not in st.finished]
            if missing:
                self.error(where, f"action {a} started before its predecessors {missing} "
                           "finished")
            if k in self.running:
                self.error(where, f"robot {k} starts {a} while running {self.running[k]}")
            if self.pos[k] != src:
                self.error(where, f"robot {k} starts {a} from {src} but stands on "
                           f"{self.pos[k]}")
            hs = st.graph.headings
            if hs is not None and self.heading is not None and self.heading[k] != hs[k][i]:
                self.error(where, f"robot {k} starts {a} with heading {hs[k][i]} but holds "
                           f"{self.heading[k]}")
            st.started[a] = t
            self.running[k] = a
            if dst != src:
                self.enter(dst, k, t)
        else:  # finish
            if a not in st.started or a in st.finished or self.running.get(k) != a:
                self.error(where, f"finish of action {a} that is not running")
                return
            st.finished[a] = t
            del self.running[k]
            if dst != src:
                self.leave(src, k)
            self.pos[k] = dst
            if self.heading is not None and st.graph.headings is not None:
                self.heading[k] = st.graph.headings[k][i + 1]
            self.last_finish[k] = t
            self.report.actions_run += 1

    def close(self) -> TraceReport:
        r = self.report
        r.plans = len(self.states)
        if not self.states:
            r.errors.append("the trace adopts no plan")
            return r
        if self.running:
            r.errors.append(f"robots {sorted(self.running)} never finished "
                            f"{sorted(self.running.values())}")
        final = self.states[-1]
        never = [a for a in final.graph.preds if a not in final.finished]
        if never and final.graph.lifelong is None:
            r.errors.append(f"plan {final.graph.plan}: actions {never[:10]} never ran "
                            f"({len(never)} in all)")
        finishes = [self.last_finish.get(k, 0.0) for k in range(len(self.pos))]
        r.soc_ms = sum(finishes)
        r.makespan_ms = max(finishes, default=0.0)
        if self.summary is None:
            r.errors.append("no summary record")
        else:
            for key, value in (("soc_ms", r.soc_ms), ("makespan_ms", r.makespan_ms)):
                if abs(float(self.summary[key]) - value) > TOLERANCE_MS:
                    r.errors.append(f"summary {key} {self.summary[key]} but the finishes "
                                    f"give {value}")
        return r


def check_trace(records: Iterable[Mapping[str, Any]]) -> TraceReport:
    """Check a whole trace, given as its records in order."""
    replay = _Replay()
    for n, rec in enumerate(records, 1):
        try:
            replay.record(n, rec)
        except (KeyError, TypeError, ValueError, IndexError) as exc:
            replay.error(f"record {n}", f"malformed {rec.get('type')!r} record: {exc!r}")
    return replay.close()


def slack_series(records: Sequence[Mapping[str, Any]],
                 times_ms: Iterable[float]) -> list[float]:
    """Δ̄F of the plan in force at each of ``times_ms`` (ascending), from the trace alone."""
    out: list[float] = []
    replay = _Replay()
    n = 0
    for t in times_ms:
        while n < len(records) and records[n].get("type") != "summary" and \
                float(records[n]["t_ms"]) <= t:
            replay.record(n + 1, records[n])
            n += 1
        out.append(fleet_slack(replay.states[-1], t) if replay.states else 0.0)
    return out


def _is_lorr_output(records: Sequence[Mapping[str, Any]]) -> bool:
    return len(records) == 1 and "actualPaths" in records[0]


def _check(argv: Sequence[str] | None) -> int:
    parser = CommandParser(
        prog="python -m tracecheck", description=__doc__.splitlines()[0] if __doc__ else None,
        epilog=f"LoRR output JSON (fleetgate lifelong --output): python -m tracecheck.lorr. "
               f"{EPILOG}")
    parser.add_argument("trace", type=Path, help="JSON-lines trace file")
    args = parser.parse_args(argv)
    try:
        records = read_trace(args.trace)
    except OSError as exc:
        raise UsageError(f"cannot read {args.trace}: {exc.strerror}") from None
    except ValueError as exc:
        raise UsageError(str(exc)) from None
    if _is_lorr_output(records):
        raise UsageError(f"{args.trace} is a LoRR output (fleetgate lifelong --output), not a "
                         f"trace: check it with python -m tracecheck.lorr {args.trace} "
                         f"--problem PROBLEM.json")
    report = check_trace(records)
    for err in report.errors:
        print(f"error: {err}")
    for c in report.collisions:
        print(f"collision: t={c.t_ms} ms {c.who} entered {c.cell} held by {', '.join(c.holders)}")
    for t, rec, mine in report.triggers:
        again = "not recomputed (lifelong)" if math.isnan(mine) else f"recomputed {mine} ms"
        print(f"trigger at {t} ms: fleet slack recorded {rec} ms, {again}")
    print(f"{report.plans} plan(s), {report.actions_run} actions, SOC {report.soc_ms:.0f} ms, "
          f"makespan {report.makespan_ms:.0f} ms: {'OK' if report.ok else 'FAILED'}")
    return 0 if report.ok else 1


def main(argv: Sequence[str] | None = None) -> int:
    """``python -m tracecheck FILE``: print the findings; exit 1 if any, 2 if the file cannot
    be read as JSON lines (one line on stderr; the exit codes of :mod:`fleetgate.userio`)."""
    return call("tracecheck", _check, argv)


if __name__ == "__main__":
    sys.exit(main())
