"""Test-only helpers for the execution core: plan generation, independent oracles, a driver.

Everything here is written from DESIGN section 2 directly, without the code under test: a
1-robust check, the Type 2 edges by brute force over all pairs, and a tiny discrete-event loop
that plays the robots and checks the executor after every event. Random 1-robust plans come
from the planning layer's generator and are re-checked with the 1-robust check.
"""

from __future__ import annotations

import enum
import heapq
import itertools
import random
from collections.abc import Sequence
from dataclasses import dataclass, field

from hypothesis import strategies as st

from gateway.execution.commands import (
    Cancel,
    Completed,
    Dispatch,
    PlanAdopted,
    SolveRequest,
    Trigger,
)
from gateway.execution.oneshot.executor import MONITOR_PERIOD_MS, Executor, Mode
from gateway.execution.oneshot.monitor import NOT_STARTED, Estimate, algorithm1
from gateway.planning.grid import Cell, Grid
from gateway.planning.plan import Plan
from gateway.planning.random_plans import open_grid, random_plan, random_walks

Action = tuple[int, int]  # (robot, action index)


def position(path: Sequence[Cell], t: int) -> Cell:
    """Cell at timestep t; the goal after the path ends."""
    return path[min(t, len(path) - 1)]


def is_one_robust(paths: Sequence[Sequence[Cell]]) -> bool:
    """DESIGN's 1-robustness, checked over every pair and timestep (plus unit moves)."""
    horizon = max(len(p) for p in paths) + 1
    for p in paths:
        for a, b in itertools.pairwise(p):
            if abs(a[0] - b[0]) + abs(a[1] - b[1]) > 1:
                return False
    for t in range(horizon):
        for k, pk in enumerate(paths):
            for j, pj in enumerate(paths):
                if j == k:
                    continue
                if position(pk, t) == position(pj, t):
                    return False
                if t >= 1 and position(pk, t) == position(pj, t - 1):
                    return False
    return True


def random_robust_plan(seed: int, width: int, height: int, robots: int,
                       horizon: int) -> list[list[Cell]]:
    """Random walks of ``horizon`` steps on an open width x height grid, at most half full
    (:func:`gateway.planning.random_plans.random_walks`, re-checked 1-robust here)."""
    if not 0 < robots <= width * height // 2:
        raise ValueError(f"{robots} robots do not fit on {width}x{height} (at most half full)")
    paths = random_walks(open_grid(width, height), robots, horizon, random.Random(seed))
    assert is_one_robust(paths)
    return paths


STEP = {(1, 0): 0, (0, 1): 1, (-1, 0): 2, (0, -1): 3}
"""Heading (0 east, 1 south, 2 west, 3 north) of a forward move by ``(dx, dy)``."""


def turning_expand(paths: Sequence[Sequence[Cell]],
                   seed: int) -> tuple[list[list[Cell]], list[list[int]]]:
    """An omni plan made a turning plan: every timestep becomes three (turn or wait, turn or
    wait, move or wait) for every robot, from random start headings; a robot turns the short
    way (one or two 90-degree turns) before each move. The cells repeat each omni cell three
    times, so a 1-robust omni plan stays 1-robust (pos(3t+3) = c(t+1), pos(3t+2) = c(t))."""
    rng = random.Random(seed)
    cells_out: list[list[Cell]] = []
    heads_out: list[list[int]] = []
    for path in paths:
        h = rng.randrange(4)
        cells, heads = [path[0]], [h]
        for a, b in itertools.pairwise(path):
            want = STEP.get((b[0] - a[0], b[1] - a[1]), h)
            turns = {0: [], 1: [want], 3: [want], 2: [(h + 1) % 4, want]}[(want - h) % 4]
            for hh in ([h] * (2 - len(turns)) + turns):
                cells.append(a)
                heads.append(hh)
            h = want
            cells.append(b)
            heads.append(h)
        cells_out.append(cells)
        heads_out.append(heads)
    return cells_out, heads_out


def turning_plan(paths: Sequence[Sequence[Cell]], headings: Sequence[Sequence[int]]) -> Plan:
    """A turning plan of cells and headings, trailing repeats of the last pose trimmed."""
    cells, heads = [list(p) for p in paths], [list(h) for h in headings]
    for c, h in zip(cells, heads, strict=True):
        while len(c) > 1 and (c[-1], h[-1]) == (c[-2], h[-2]):
            c.pop()
            h.pop()
    return Plan(tuple(tuple(c) for c in cells), tuple(tuple(h) for h in heads))


def brute_type2(paths: Sequence[Sequence[Cell]]) -> list[tuple[int, int, int, int]]:
    """Type 2 edges straight from the definition, comparing all pairs of actions."""
    out = []
    for k, pk in enumerate(paths):
        for i in range(len(pk) - 1):
            u = pk[i]
            if u == pk[i + 1]:
                continue
            for k2, p2 in enumerate(paths):
                if k2 == k:
                    continue
                for j in range(i + 1, len(p2) - 1):
                    if p2[j + 1] == u != p2[j]:
                        out.append((k, i, k2, j))
                        break
    return sorted(out)


def brute_predecessors(paths: Sequence[Sequence[Cell]], drop_waits: bool,
                       headings: Sequence[Sequence[int]] | None = None
                       ) -> dict[Action, set[Action]]:
    """Every action's ADG predecessors (Type 1: the previous kept action; Type 2: brute force);
    with ``headings`` a turn (same cell, other heading) is kept, not a wait."""
    preds: dict[Action, set[Action]] = {}
    for k, p in enumerate(paths):
        prev = None
        for i in range(len(p) - 1):
            turn = headings is not None and headings[k][i] != headings[k][i + 1]
            if drop_waits and p[i] == p[i + 1] and not turn:
                continue
            preds[(k, i)] = {prev} if prev is not None else set()
            prev = (k, i)
    for k, i, k2, j in brute_type2(paths):
        preds[(k2, j)].add((k, i))
    return preds


def snapshot(obj: object) -> object:
    """The whole reachable state of an object as plain, comparable data."""
    if obj is None or isinstance(obj, bool | int | float | str | enum.Enum):
        return obj
    if isinstance(obj, bytearray | bytes):
        return bytes(obj)
    if isinstance(obj, list | tuple):
        return (type(obj).__name__, [snapshot(x) for x in obj])
    if isinstance(obj, set):
        return ("set", sorted(obj))
    if isinstance(obj, dict):
        return ("dict", [(snapshot(k), snapshot(v)) for k, v in obj.items()])
    if hasattr(obj, "__dict__"):
        return (type(obj).__name__, {k: snapshot(v) for k, v in vars(obj).items()})
    if hasattr(obj, "__slots__"):
        return (type(obj).__name__, {s: snapshot(getattr(obj, s)) for s in obj.__slots__})
    return ("opaque", id(obj))


@dataclass
class _PlanLog:
    """What the driver saw of one plan."""

    paths: list[list[Cell]]
    adopted_ms: float
    preds: dict[Action, set[Action]]
    headings: list[list[int]] | None = None
    dispatched: list[Action] = field(default_factory=list)
    started: dict[Action, float] = field(default_factory=dict)
    finished: dict[Action, float] = field(default_factory=dict)
    delta0: list[float] = field(default_factory=list)


class Driver:
    """A discrete-event loop playing the robots for an executor, checking it after every event.

    Robots execute whatever is dispatched: they may take a random while to begin, get blocked
    for a while first, and take a random time to move; a Cancel is honoured if the robot has not
    begun, otherwise (sometimes, to exercise late reports) it starts anyway. Replans may be
    requested by the operator at random times; a SolveRequest is answered with the rest of each
    robot's current path ("shifted" plan) or, sometimes, by abandoning.
    """

    def __init__(self, ex: Executor, seed: int, *, replan_at_ms: float | None = None,
                 abandon_prob: float = 0.0, check_monitor: bool = True) -> None:
        self.ex = ex
        self.rng = random.Random(seed)
        self.replan_at_ms = replan_at_ms
        self.abandon_prob = abandon_prob
        self.check_monitor = check_monitor
        self.queue: list[tuple[float, int, str, tuple[object, ...]]] = []
        self.seq = 0
        self.plans: list[_PlanLog] = []
        self.robot_token = [0] * len(ex.plan.paths)
        self.robot_begun = [False] * len(ex.plan.paths)
        self.last_finish = [0.0] * len(ex.plan.paths)
        self.completed: Completed | None = None
        self.events = 0
        self.triggers: list[Trigger] = []

    def _at(self, t: float, kind: str, *args: object) -> None:
        self.seq += 1
        heapq.heappush(self.queue, (t, self.seq, kind, args))

    def run(self, max_events: int = 200_000) -> Completed:
        """Run to completion; return the Completed command."""
        self.ex.start(0.0)
        self._handle(0.0)
        self._at(MONITOR_PERIOD_MS, "tick")
        if self.replan_at_ms is not None:
            self._at(self.replan_at_ms, "replan")
        while self.completed is None:
            assert self.queue, "the run stalled: no event pending and not completed"
            self.events += 1
            assert self.events < max_events, "the run does not terminate"
            t, _, kind, args = heapq.heappop(self.queue)
            self._apply(t, kind, args)
            self._handle(t)
        return self.completed

    def _apply(self, t: float, kind: str, args: tuple[object, ...]) -> None:
        ex = self.ex
        if kind == "tick":
            ex.tick(t)
            self._at(t + MONITOR_PERIOD_MS, "tick")
            return
        if kind == "replan":
            if ex.mode is Mode.RUNNING and ex.replans < ex.max_replans:
                ex.request_replan(t)
            return
        if kind == "solve":
            (plan,) = args
            assert isinstance(plan, Plan)
            if self.rng.random() < self.abandon_prob:
                ex.abandon_replan(t)
            else:
                ex.adopt_plan(plan, t)
            return
        robot, plan_id, action, token = args
        assert isinstance(robot, int) and isinstance(plan_id, int) and isinstance(action, int)
        if token != self.robot_token[robot]:
            return  # superseded by a cancel
        log = self.plans[plan_id]
        if kind == "blocked":
            ex.blocked(robot, plan_id, action, t)
        elif kind == "unblocked":
            ex.unblocked(robot, plan_id, action, t)
        elif kind == "start":
            self.robot_begun[robot] = True
            ex.started(robot, plan_id, action, t)
            assert (robot, action) not in log.started, "an action started twice"
            log.started[(robot, action)] = t
            self._at(t + self.rng.choice([1000, 1000, 700, 1800]), "finish", robot, plan_id,
                     action, token)
        elif kind == "finish":
            ex.finished(robot, plan_id, action, t)
            log.finished[(robot, action)] = t
            self.last_finish[robot] = t
            self.robot_begun[robot] = False
        elif kind == "cancelled":
            ex.cancelled(robot, plan_id, action, t)

    def _handle(self, now: float) -> None:
        """React to the executor's commands and check its state."""
        ex = self.ex
        for cmd in ex.drain():
            if isinstance(cmd, PlanAdopted):
                paths = [list(p) for p in cmd.paths.paths]
                assert cmd.plan == len(self.plans)
                heads = None if cmd.paths.headings is None else [
                    list(h) for h in cmd.paths.headings]
                self.plans.append(_PlanLog(paths, now,
                                           brute_predecessors(paths, ex.drop_waits, heads),
                                           heads))
                self.plans[-1].delta0 = self._oracle(self.plans[-1], now).delta
            elif isinstance(cmd, Dispatch):
                self._on_dispatch(cmd, now)
            elif isinstance(cmd, Cancel):
                self._on_cancel(cmd, now)
            elif isinstance(cmd, SolveRequest):
                assert list(cmd.starts) == [ex.robot_cell(r) for r in range(len(cmd.starts))]
                self._at(now + self.rng.choice([0, 100, 250]), "solve", self._shifted(cmd))
            elif isinstance(cmd, Trigger):
                self.triggers.append(cmd)
            elif isinstance(cmd, Completed):
                self.completed = cmd
        if self.check_monitor:
            assert ex.monitor.now_ms <= ex.now_ms
            self.check_monitor_state(ex.monitor.now_ms)

    def _on_dispatch(self, cmd: Dispatch, now: float) -> None:
        """Check a dispatch and schedule the robot's reports for it."""
        log = self.plans[cmd.plan]
        key = (cmd.robot, cmd.action)
        assert cmd.plan == len(self.plans) - 1
        assert all(p in log.finished for p in log.preds[key]), "dispatched too early"
        assert key not in log.started
        done = [a for (r, a) in log.finished if r == cmd.robot]
        assert all(a < cmd.action for a in done), "robot's actions out of order"
        path, heads = log.paths[cmd.robot], log.headings
        h0, h1 = (None, None) if heads is None else heads[cmd.robot][cmd.action:cmd.action + 2]
        assert (cmd.src, cmd.dst, cmd.src_heading, cmd.dst_heading) == (
            path[cmd.action], path[cmd.action + 1], h0, h1)
        kind = "move" if cmd.src != cmd.dst else "wait" if h0 == h1 else "turn"
        assert cmd.duration_ms == self.ex.durations[cmd.robot].of(kind)
        log.dispatched.append(key)
        self._begin(cmd.robot, cmd.plan, cmd.action, now)

    def _begin(self, robot: int, plan_id: int, action: int, now: float) -> None:
        """The robot takes up the action: it may wait a while (blocked or not), then starts."""
        self.robot_token[robot] += 1
        token = self.robot_token[robot]
        begin = now + self.rng.choice([0, 0, 0, 30, 400])
        if self.rng.random() < 0.2:
            self._at(now, "blocked", robot, plan_id, action, token)
            begin += self.rng.choice([200, 1500, 3500])
            if self.rng.random() < 0.5:
                self._at(begin, "unblocked", robot, plan_id, action, token)
        self._at(begin, "start", robot, plan_id, action, token)

    def _on_cancel(self, cmd: Cancel, now: float) -> None:
        """Honour a cancel (mostly) if the robot has not begun to move."""
        if not self.robot_begun[cmd.robot] and self.rng.random() < 0.8:
            self.robot_token[cmd.robot] += 1
            self._at(now + self.rng.choice([0, 50]), "cancelled", cmd.robot, cmd.plan,
                     cmd.action, self.robot_token[cmd.robot])

    def _shifted(self, request: SolveRequest) -> Plan:
        """Each robot's remaining path (and headings) from where it stands (same goals)."""
        log = self.plans[-1]
        paths, heads = [], []
        for r, path in enumerate(log.paths):
            done = [a for (k, a) in log.finished if k == r]
            cut = max(done) + 1 if done else 0
            rest = path[cut:]
            assert rest[0] == request.starts[r] and rest[-1] == request.goals[r]
            paths.append(rest)
            if log.headings is not None:
                assert request.headings is not None
                assert log.headings[r][cut] == request.headings[r]
                heads.append(log.headings[r][cut:])
        if log.headings is None:
            assert request.headings is None
            return Plan.of(paths)
        return turning_plan(paths, heads)

    def _oracle(self, log: _PlanLog, now: float) -> Estimate:
        adg = self.ex.adg
        keys = [(adg.robot_of[v], adg.step_of[v]) for v in range(adg.n_vertices)]
        return algorithm1(adg, now_ms=now, action_ms=self.ex.monitor.tx,
                          release_ms=[log.adopted_ms] * adg.n_robots,
                          started_ms=[log.started.get(k) for k in keys],
                          finished_ms=[log.finished.get(k) for k in keys])

    def check_monitor_state(self, now: float) -> None:
        """The incremental monitor equals the full Algorithm 1 recomputation."""
        ex, log = self.ex, self.plans[-1]
        mon, adg = ex.monitor, ex.adg
        full = self._oracle(log, now)
        inc = mon.snapshot()
        assert inc.ts == full.ts and inc.tc == full.tc and inc.delta == full.delta
        assert inc.delta0 == log.delta0
        growth = [d - d0 for d, d0 in zip(inc.delta, log.delta0, strict=True)]
        unstarted = [v for v in range(adg.n_vertices) if mon.state(v) == NOT_STARTED]
        assert mon.fleet_slack() == max((growth[v] for v in unstarted), default=0.0)
        for r in range(adg.n_robots):
            mine = [growth[v] for v in unstarted if adg.robot_of[v] == r]
            assert mon.robot_slack(r) == max(mine, default=0.0)
        assert ex.soc_ms == sum(self.last_finish)


Delays = dict[tuple[int, int], int]
"""Extra ms of a robot's action: ``(robot, action index) -> ms``."""


@st.composite
def delayed_plans(draw: st.DrawFn, min_agents: int, min_steps: int) -> tuple[Grid, Plan, Delays]:
    """A random plan on a small open grid (3-6 x 3-6 cells, at least ``min_agents`` robots and
    ``min_steps`` steps) and random extra delays of up to 8 of its actions."""
    w, h = draw(st.integers(3, 6)), draw(st.integers(3, 6))
    n = draw(st.integers(min_agents, max(min_agents, w * h // 3)))
    grid = open_grid(w, h)
    plan = random_plan(grid, n, draw(st.integers(min_steps, 14)),
                       random.Random(draw(st.integers(0, 2**32 - 1))))
    delays = draw(st.dictionaries(st.tuples(st.integers(0, n - 1), st.integers(0, 12)),
                                  st.integers(1, 4000), max_size=8))
    return grid, plan, delays
