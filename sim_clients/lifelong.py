"""Lifelong operation in virtual time under the League of Robot Runners (LoRR) rules.

The simulation advances in execution ticks. A forward move or a turn takes ``agent_counter``
ticks (the problem's ``agentCounter``); a robot in a delay (the problem's ``delayConfig``,
drawn per tick by :class:`DelayModel`) makes no progress. The planner runs periodically, every
``period`` ticks at the earliest (LoRR's ``planCommTimeLimit`` / ``actionMoveTimeLimit``): it
assigns tasks to robots that have none (:mod:`gateway.execution.lifelong.tasks`), plans a window of
``window`` timesteps from the robots' committed end states (:mod:`gateway.planning.pibt`): the
lifelong executor's own call (``window_request``, answered by its ``WindowPlanner``), given
the simulator's holds (actions of ``agent_counter`` ticks) and its delayed robots as the late
(whose actions not started yet are taken back first, with every action waiting on them:
:meth:`~gateway.execution.lifelong.live_adg.LiveADG.retract`, as the LoRR Start-Kit's executor
drops staged actions that cannot run), and its result is appended to the live ADG
(:mod:`gateway.execution.lifelong.live_adg`) when it arrives: ``ceil(planner time / tick)``
ticks after the call, its compute time charged as measured CPU time
(``planner_time="measured"``), as zero, or as a fixed number of ms (both exactly
reproducible). Meanwhile robots keep executing what is committed, so they never stop
for a replan. A robot starts its next committed action at a tick only if the action's Type 2
dependency finished at an earlier tick, so no two robots ever hold a cell at the same tick
(a moving robot holds both cells of its move).

An errand is done when its robot completes the action that brings it onto the errand's cell
(or its committed actions end there); a finished task reveals the next one.
"""

from __future__ import annotations

import gc
import math
import time
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from gateway.execution.lifelong.errands import ErrandBook, TaskDistances
from gateway.execution.lifelong.executor import Segment, WindowPlanner, window_request
from gateway.execution.lifelong.live_adg import CCW, CW, FORWARD, LiveADG
from gateway.execution.lifelong.tasks import SCHEDULERS, TaskPool, wait_percentiles
from gateway.planning.guidance import (
    MOVE,
    corridor_lanes,
    corridor_share,
    crisscross,
    one_way_doors,
)
from gateway.planning.lorr import DelayConfig, LorrProblem, compress_path
from gateway.planning.pibt import StateSpace, compact_needed, exact_fits

TICK_MS = 100.0
"""LoRR's default execution tick (``actionMoveTimeLimit``)."""
PLAN_PERIOD_MS = 1000.0
"""LoRR's default minimum time between plan updates (``planCommTimeLimit``)."""
DELAY_CHARGE = 4.0
"""A robot in a delay is charged this many times the delay model's mean duration (in actions)
on top of its distance when the scheduler weighs it for a task, so tasks go to robots that
can go (room-64-64-16, 10-30 tick delays, 8 delay seeds: mean 111 tasks without, 117 with 4x,
113-114 with about 2x, 9x or an infinite charge; random-64-64-10's 1-4 tick delays: neutral)."""
MAX_WAIT_TICKS = 600
"""Default fairness bound (:attr:`~gateway.execution.lifelong.tasks.TaskPool.max_wait`): 60 s
at 100 ms a tick (the gateway's ``lifelong.max_wait_ms`` is 45 s). On the 600-tick shared LoRR
runs (maze, room, random, 3 delay seeds, planner time zero) 600 finishes as many tasks as no
bound (235, 342, 1410 summed, against 241, 330, 1411), 450 costs 4-7% (225, 317, 1349): aging
from half the bound then reaches tasks the short run would not have finished anyway."""
REASSIGN_BATCH = 1000
"""Robots whose unstarted tasks one reassignment releases, in turn (all of a fleet up to this
size, so the shared problems' runs are unchanged): on the competition's large maps, releasing
all of 10,000 robots' unstarted tasks at every call made the matching 2-4 s of CPU a call."""
PLANNER_BUDGET = 2 << 30
"""Bytes of the planner's table cache (exact tables over the turning states when two per robot
fit: what ``lanes`` needs)."""
LANES = 3
"""The default crisscross lanes' penalty (:mod:`gateway.planning.guidance`: a move against its
lane costs 2.5 moves) of a run whose exact tables fit :data:`PLANNER_BUDGET` (else none).
Shared LoRR problems, 600 ticks, delay seeds 0-2, load 14-25, tasks without lanes / penalty 1
/ penalty 3: maze 75.7 / 84.3 / 84.7, room 121.3 / 120.3 / 136.7 (seeds 0-7: 124.3 / 125.3 /
132.9), random 456 (2 seeds) / 499.7 / 500.0, city 246.3 / 251.0 / 250.0; random-400 under
the 2024 rules (planner seeds 0-4) 445.2 / 493.8 / 497.8 (penalty 4: 499.8, 6: 486.4; room
penalty 5: 131.0, maze 83.3)."""
LANES_ROOMS = 1
"""The default lanes' penalty on a map with one-way doors (:data:`DOORS`): inside rooms the
crisscross lanes only break ties. Room, 600 ticks, doors 20, delay seeds 0-23: lanes 1 143.5
tasks, 3 140.6, 2 140.3 (seeds 0-11), 5 139.4 (seeds 0-11); lanes 1 without doors 133.0 (seeds
0-11)."""
CORRIDORS = 0.5
"""The share of a map's free cells in one-cell corridors (:func:`~gateway.planning.guidance.
corridor_share`) from which a run whose tables are over the cells, not exact (thousands of
robots on a large map), is guided by :func:`~gateway.planning.guidance.corridor_lanes`
(:data:`CORRIDOR_LANES`): LoRR's warehouse_large (0.63), not the game map brc202d (0.009)."""
CORRIDOR_LANES = 20
"""The default penalty of a move against its corridor's lane (half-moves: ten moves, nearly
one way) where :data:`CORRIDORS` applies. warehouse_large, 10,000 robots, 600 ticks, station
cap 4, one run each at load 6-9: no lanes 1,105 tasks (1,168 at load 1-3), penalty 1 1,300,
3 1,314, 8 1,358, 20 1,377, 40 1,327."""
DOORS = 20
"""The default penalty of a move against a one-way door (:func:`~gateway.planning.guidance.
one_way_doors`, half-moves) of a run whose exact tables fit :data:`PLANNER_BUDGET` (else
none). Room, 600 ticks, lanes 3, delay seeds 0-11: no doors 133.9 tasks, 16 140.8, 20 140.75,
24 137.75, 30 140.7, 40 138.1; the other shared maps have no such doors (no change)."""
TURN_COST = 6
"""What a turn costs in the guided tables (half-moves: 3 moves, though it takes one action) on a
map without one-way doors: paths with fewer turns are preferred, and a robot switches less
between routes as the crowd changes. Random-64-64-10, 600 ticks, delay seeds 0-11: turns of 2
(one move) 523.3 tasks, 4 529.4, 6 531.6 (seeds 0-5: 5 527.5, 8 528.0); maze 85.8 -> 86.1, city
seed 0 250 -> 257. Room, with its one-way doors, keeps 2 (143.8 over seeds 0-11; 4: 142.1, 6:
142.8), and so does a run under the 2024 rules (one tick an action: random-400 529.0 with 2,
527.5 with 6, planner seeds 0-5)."""
LNS_ROUNDS = 200
"""The most rounds of LNS (:func:`~gateway.planning.lns.refine`, groups replanned by priority)
over each window: half a round per robot up to this, under an action of more ticks than one
and on a map without one-way doors. A planning call takes about 25 ms more (random-400: 0.026
-> 0.050 s on an idle machine). Shared LoRR problems, 600 ticks, tasks without LNS / with:
random (200 rounds) delay seeds 0-5 531.5 / 539.7 (each seed 536 or more, 519-540 before);
maze (20 rounds) seeds 0-23 85.4 / 84.9 (200 rounds: 83.9); city (200, groups in a random
order) seeds 0-5 248.8 / 249.0; room seeds 0-11 143.8 / 142.0 (50 rounds 142.0, groups of 10
within 3 cells 143.5, single robots 131.5): off there. Random, 100 rounds (random order)
538.5, 150: 539.0, 500: 542.7 with calls over 100 ms (a tick of latency more). Not under the
2024 rules (one tick an action): their windows of 10 timesteps make the searches about 300 ms
a call, random-400 530.3 -> 464.7 tasks."""
_LETTER = {FORWARD: "F", CW: "R", CCW: "C"}
_OMNI_LETTER = {1: "e", -1: "w"}  # omni moves (not LoRR): e/s/w/n by direction


class DelayModel:
    """LoRR's delay generator: each tick, robots not in a delay may start one.

    ``bernoulli``: each available robot with probability ``p_delay``; ``poisson``:
    ``Poisson(team * p_delay)`` available robots at random. Durations are uniform integers in
    ``[min_delay, max_delay]`` or a rounded, clamped Gaussian. Seeded by the config's seed.
    """

    def __init__(self, config: DelayConfig, n_robots: int) -> None:
        self.config = config
        self.n = n_robots
        self.rng = np.random.default_rng(config.seed)
        self.remaining = np.zeros(n_robots, dtype=np.int64)
        self.intervals: list[list[tuple[int, int]]] = [[] for _ in range(n_robots)]

    def _duration(self, k: int) -> list[int]:
        c = self.config
        if c.min_delay == c.max_delay:
            return [c.min_delay] * k
        if c.duration_model == "uniform":
            return self.rng.integers(c.min_delay, c.max_delay + 1, size=k).tolist()
        span = c.max_delay - c.min_delay
        raw = self.rng.normal(c.min_delay + span * c.gauss_mean_ratio,
                              span * c.gauss_std_ratio, size=k)
        return np.clip(np.rint(raw), c.min_delay, c.max_delay).astype(np.int64).tolist()

    def tick(self, t: int) -> npt.NDArray[np.bool_]:
        """Advance to tick ``t``; returns the mask of robots delayed during it."""
        np.maximum(self.remaining - 1, 0, out=self.remaining)
        c = self.config
        if c.p_delay > 0:
            free = np.flatnonzero(self.remaining == 0)
            if c.event_model == "bernoulli":
                chosen = free[self.rng.random(free.size) < c.p_delay]
            else:
                k = min(int(self.rng.poisson(self.n * c.p_delay)), free.size)
                chosen = self.rng.permutation(free)[:k] if k else free[:0]
            if chosen.size:
                durations = self._duration(chosen.size)
                self.remaining[chosen] = durations
                for robot, d in zip(chosen.tolist(), durations, strict=True):
                    self.intervals[robot].append((t, t + d))
        return self.remaining > 0



@dataclass(frozen=True)
class LifelongConfig:
    """One lifelong run: problem, ticks, motion model and planner settings."""

    problem: LorrProblem
    ticks: int = 600
    turning: bool = True
    period: int = 10
    window: int = 0  # timesteps per planning call; 0: enough to cover a period
    planner_time: str | float = "measured"  # "measured", "zero" or ms per call
    tick_ms: float = TICK_MS
    scheduler: str = "shortest"
    max_wait: int | None = MAX_WAIT_TICKS  # fairness bound (ticks; None: none), TaskPool.max_wait
    reassign: int = 1  # planning calls between reassignments of unstarted tasks; 0: never
    reassign_batch: int = REASSIGN_BATCH  # robots whose unstarted task a reassignment releases
    station_cap: int | None = None  # robots sent to one first-errand cell at a time (TaskPool)
    lanes: int | None = None  # penalty of a move against its crisscross lane
    # (gateway.planning.guidance; turning, exact tables), or with tables over the cells its
    # corridor's lane (corridor_lanes); 0: no lanes; None: LANES if exact tables fit
    # (LANES_ROOMS on a map with one-way doors)
    doors: int | None = None  # penalty of a move against a one-way door (guidance.
    # one_way_doors; turning, exact tables); 0: none; None: DOORS if exact tables fit
    turn_cost: int | None = None  # a turn's cost in the guided tables (StateSpace.turn);
    # None: TURN_COST under an action of more ticks than one, else or on a map with one-way
    # doors MOVE
    crowd: bool = True  # tables guided by the crowd (StateSpace.guide) where they are exact
    warm: bool = True  # compute the robots' later errands' tables between calls (warm_times)
    turn_to_leaving: bool | None = None  # WindowedPIBT.turn_to_leaving; None: under one tick
    # an action (the 2024 rules) only: there random-400 509 -> 525 tasks, under the 2026 rules
    # room with its one-way doors 144.7 -> 138.0 (maze, random, city unchanged)
    lns: int | None = None  # rounds of LNS over each window (gateway.planning.lns); None:
    # half a round per robot up to LNS_ROUNDS under an action of more ticks than one (the 2026
    # rules) on a map without one-way doors, else none
    seed: int = 0
    output_window: int = 1000


@dataclass
class LifelongResult:
    """What a run did: finished tasks, per-tick actions, events, planner times (s), and the
    tasks' assignment waits (ticks, :meth:`~gateway.execution.lifelong.tasks.TaskPool.waits`)."""

    ticks: int
    finished: int
    letters: list[bytearray]
    snapshots: list[list[tuple[int, int, int]]]
    events: list[tuple[int, int, int, int]]
    tasks: list[tuple[int, int, tuple[int, ...]]]
    planner_times: list[float]
    delay_intervals: list[list[tuple[int, int]]]
    starts: list[tuple[int, int]]
    sum_of_cost: int
    max_pending: int = 0
    calls: int = 0
    waits: list[float] = field(default_factory=list)
    warm_times: list[float] = field(default_factory=list)
    """CPU seconds after each call computing the tables of the robots' later errands (the
    gateway's planner worker does this between calls, :class:`~gateway.server.runs.
    planner_process.Warm`; here on the second core: not charged to the call)."""
    extra: dict[str, float] = field(default_factory=dict)


@dataclass(frozen=True)
class _Pending:
    """A planned window on its way: it is appended at tick ``arrival``."""

    arrival: int
    states: Sequence[Sequence[int]]
    reached: Sequence[Sequence[int]]
    tasks_of: list[int]


def _planner_ms(mode: str | float, cpu_s: float) -> float:
    if mode == "measured":
        return cpu_s * 1000.0
    if mode == "zero":
        return 0.0
    return float(mode)


@contextmanager
def _collector_paused() -> Iterator[None]:
    """Python's cyclic garbage collector off inside (a planning call), as it was after, so
    it collects between calls, when the planner would otherwise wait for the next one. On
    random-400 under the 2024 rules a collection that fell inside a call made it 105-127 ms
    instead of about 50: a tick of latency more, and one run of the bench finished 503 tasks
    instead of 532."""
    enabled = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        if enabled:
            gc.enable()


def run_lifelong(cfg: LifelongConfig,
                 on_progress: Callable[[int, int], None] | None = None) -> LifelongResult:
    """Simulate ``cfg.ticks`` ticks; ``on_progress(tick, finished)`` after each planning call."""
    prob = cfg.problem
    grid = prob.grid
    n = prob.team_size
    counter = prob.agent_counter
    if cfg.scheduler not in SCHEDULERS:
        raise ValueError(f"unknown scheduler {cfg.scheduler!r}")
    schedule = SCHEDULERS[cfg.scheduler]
    exact = cfg.turning and exact_fits(grid, n, PLANNER_BUDGET)
    doors = cfg.doors if cfg.doors is not None else DOORS if exact else 0
    if (doors or cfg.lanes) and not cfg.turning:
        raise ValueError("lanes and doors guide the turning model only")
    one_way = one_way_doors(grid, doors)
    lanes = cfg.lanes
    if lanes is None and exact:
        lanes = LANES_ROOMS if one_way.any() else LANES
    elif lanes is None:
        lanes = (CORRIDOR_LANES if not compact_needed(grid, n, PLANNER_BUDGET)
                 and corridor_share(grid) >= CORRIDORS else 0)
    guided = cfg.crowd and exact  # the crowd weighs exact tables (lanes 0: none)
    if exact:
        forward = (crisscross(grid, lanes) + one_way if lanes or one_way.any() or guided
                   else None)
    else:  # tables over the cells: lanes along a warehouse's one-cell aisles
        forward = corridor_lanes(grid, lanes) if lanes else None
    turn_cost = cfg.turn_cost
    if turn_cost is None:
        turn_cost = (MOVE if one_way.any() or forward is None or counter == 1 or not exact
                     else TURN_COST)
    space = StateSpace(grid, cfg.turning, budget_bytes=PLANNER_BUDGET, robots=n,
                       guidance=forward, turn=turn_cost)
    turn = cfg.turn_to_leaving if cfg.turn_to_leaving is not None else counter == 1
    planner = WindowPlanner(grid, n, cfg.turning, seed=cfg.seed, space=space, guided=guided,
                            turn_to_leaving=turn,
                            lns=cfg.lns if cfg.lns is not None else
                            min(LNS_ROUNDS, n // 2) if counter > 1 and not one_way.any()
                            else 0)
    headings = [0] * n
    adg = LiveADG(grid, prob.starts, headings if cfg.turning else None)
    delays = DelayModel(prob.delay, n)
    window = cfg.window or math.ceil(cfg.period / counter)
    # the scheduler's distances: exact moves; a robot in a delay competes for tasks with a
    # charge, so tasks go to robots that can go. On a large map the planner's tables are the
    # moves over the free cells too: one cache serves both (the robots' goals are errands)
    distances = TaskDistances(grid, charge=round(DELAY_CHARGE * prob.delay.mean_duration
                                                 / counter),
                              space=None if space.exact or space.compact
                              or space.guidance is not None else space)
    pool = TaskPool(prob.tasks, max(1, int(prob.num_tasks_reveal * n)), leg=distances.leg,
                    max_wait=cfg.max_wait, station_cap=cfg.station_cap)
    book = ErrandBook(pool, n)
    # LoRR's preprocessing (up to 30 s before the first tick): the scheduler's tables of the
    # revealed tasks' errands but the last (their first errands and their legs), which the
    # first call would compute otherwise
    cpu0 = time.thread_time()
    distances.space.prefetch([c for task in pool.open.values() for c in task.errands[:-1]])
    if guided:  # the crowd at the start weighs the first tables (and its search is compiled
        # here, not in the first call: 0.6 s of CPU on a fresh machine)
        space.guide(prob.starts, ())
    if space.exact or space.compact or space.guidance is not None:  # and the planner's own
        # tables of the first goals (the city's first call took 2.5 s of CPU without them: 25
        # ticks before any robot moved); exact guided tables cost five breadth-first ones: all
        # the errands' (a first call of 0.4 s)
        space.prefetch([c for task in pool.open.values()
                        for c in (task.errands if space.guidance is not None and space.exact
                                  else task.errands[:1])])
    preprocess_s = time.thread_time() - cpu0

    cell = list(prob.starts)
    heading = list(headings)
    progress = [0] * n  # ticks done of the running action (0: idle)
    letters = [bytearray() for _ in range(n)]
    snapshots: list[list[tuple[int, int, int]]] = [[] for _ in range(n)]
    events: list[tuple[int, int, int, int]] = []
    released: list[tuple[int, int, tuple[int, ...]]] = []
    recorded: set[int] = set()
    planner_times: list[float] = []
    warm_times: list[float] = []
    pending: _Pending | None = None
    next_call = 0
    sum_of_cost = 0
    max_pending = 0
    idle = [0, 0, 0]  # robot-ticks delayed, waiting for a dependency, without committed work
    width = grid.width

    def errands_reached(r: int, t: int) -> None:
        for task_id in book.reach(r, adg.done[r]):
            task = pool.tasks[task_id]
            events.append((t, r, task_id, task.done + 1))
            pool.errand_done(task_id, t)

    def apply(t: int, states: Sequence[Sequence[int]], reached: Sequence[Sequence[int]],
              tasks_of: list[int]) -> None:
        """Append a planned window to the ADG and register its errand markers."""
        cells = [[space.cell_of[s] for s in row] for row in states]
        heads = [[space.heading_of(s) for s in row] for row in states] if cfg.turning else None
        book.register(adg.appended, states, reached, tasks_of)
        adg.append(cells, heads)
        for r in range(n):
            errands_reached(r, t)

    def plan(t: int) -> tuple[Segment, list[int], float]:
        """The planning call at tick ``t``: its window, the tasks it works on (for
        :meth:`~gateway.execution.lifelong.errands.ErrandBook.register`) and its CPU seconds.
        Python's cyclic collector is paused in it: it runs between calls."""
        with _collector_paused():
            cpu0 = time.thread_time()
            # a delayed robot's actions not started yet are taken back, with every action
            # that waits on them (a robot behind it), so the window plans those robots anew
            # around it instead of leaving them queued behind it for the whole delay
            adg.retract([(1 if progress[r] else 0) if delayed[r] else adg.pending(r)
                         for r in range(n)], cell, heading)
            book.retract(adg.appended, t)
            # a robot's new moves start when it can make them: it waits in the window for its
            # committed actions but one (the one it finishes while the next window arrives), so
            # others do not plan to enter cells it leaves long after the plan says; robots in a
            # delay compete for tasks with a charge, and others are planned around them
            hold = [-(-(adg.pending(r) * counter - progress[r]) // counter) - 1
                    for r in range(n)]
            # unstarted tasks go back to the scheduler, of at most reassign_batch robots in
            # turn (the matching's work grows with the robots it places)
            first = len(planner_times) // max(1, cfg.reassign) * cfg.reassign_batch
            req, assigned = window_request(
                len(planner_times), book, adg, schedule, distances, t,
                release=bool(cfg.reassign) and len(planner_times) % cfg.reassign == 0,
                release_robots=None if cfg.reassign_batch >= n else
                [(first + i) % n for i in range(cfg.reassign_batch)],
                late=delayed, hold=hold, steps=window, turning=cfg.turning)
            for _, task_id in assigned:
                if task_id not in recorded:
                    recorded.add(task_id)
                    task = pool.tasks[task_id]
                    released.append((task_id, task.release_tick, task.errands))
            win = planner(req)
            return win, book.planned(win.reached), time.thread_time() - cpu0

    delayed = [False] * n
    for t in range(cfg.ticks):
        if pending is not None and pending.arrival <= t:
            apply(t, pending.states, pending.reached, pending.tasks_of)
            pending = None
        if pending is None and t >= next_call:
            win, tasks_of, cpu = plan(t)
            planner_times.append(cpu)
            if cfg.warm:  # tables for after the robots' present errands, before they are due
                cpu0 = time.thread_time()
                space.prefetch([c for g in book.goals() for c in g[1:]])
                warm_times.append(time.thread_time() - cpu0)
            delay_ticks = math.ceil(_planner_ms(cfg.planner_time, cpu) / cfg.tick_ms)
            pending = _Pending(t + delay_ticks, win.states, win.reached, tasks_of)
            next_call = t + cfg.period
            if delay_ticks == 0:
                apply(t, win.states, win.reached, tasks_of)
                pending = None
            if on_progress is not None:
                on_progress(t, pool.finished)
        max_pending = max(max_pending, adg.n_pending())
        delayed = delays.tick(t).tolist()
        if t % cfg.output_window == 0:
            for r in range(n):
                snapshots[r].append((cell[r], heading[r], progress[r]))
        # starts: decided on the state at the beginning of the tick
        for r in range(n):
            if progress[r] == 0 and not delayed[r] and adg.is_ready(r):
                progress[r] = -1  # starts this tick
        for r in range(n):
            p = progress[r]
            if p == 0 or delayed[r]:
                letters[r].append(87)  # "W"
                if delayed[r]:
                    idle[0] += 1
                elif adg.pending(r):
                    idle[1] += 1
                else:
                    idle[2] += 1
                continue
            a = adg.head(r)
            assert a is not None
            if a.kind == FORWARD and not cfg.turning:
                d = a.cell - cell[r]
                letters[r].append(ord(_OMNI_LETTER.get(d, "s" if d == width else "n")))
            else:
                letters[r].append(ord(_LETTER[a.kind]))
            sum_of_cost += 1
            p = 1 if p < 0 else p + 1
            if p >= counter:
                adg.finish(r)
                cell[r], heading[r] = a.cell, a.heading
                progress[r] = 0
                errands_reached(r, t)
            else:
                progress[r] = p
    starts_out = [divmod(c, width) for c in prob.starts]
    return LifelongResult(
        ticks=cfg.ticks, finished=pool.finished, letters=letters, snapshots=snapshots,
        events=events, tasks=released, planner_times=planner_times,
        delay_intervals=delays.intervals, starts=starts_out, sum_of_cost=sum_of_cost,
        max_pending=max_pending, calls=len(planner_times), waits=pool.waits(cfg.ticks),
        warm_times=warm_times,
        extra={"delayed": idle[0] / (n * cfg.ticks), "waiting": idle[1] / (n * cfg.ticks),
               "no_work": idle[2] / (n * cfg.ticks), "preprocess_s": preprocess_s})


def lorr_output(cfg: LifelongConfig, res: LifelongResult) -> dict[str, object]:
    """The LoRR output JSON of a run (``Input_Output_Format.md``)."""
    grid = cfg.problem.grid
    paths = [compress_path(grid, res.snapshots[r], res.letters[r].decode("ascii"),
                           cfg.output_window) for r in range(len(res.letters))]
    names = "ESWN"
    width = grid.width
    return {
        "actionModel": "MAPF_T" if cfg.turning else "MAPF",
        "AllValid": "Yes",
        "teamSize": len(res.letters),
        "agentMaxCounter": cfg.problem.agent_counter,
        "outputSegmentSize": cfg.output_window,
        "start": [[row, col, names[0]] for row, col in res.starts],
        "numTaskFinished": res.finished,
        "sumOfCost": res.sum_of_cost,
        "makespan": res.ticks,
        "actualPaths": paths,
        "plannerTimes": res.planner_times,
        "errors": [],
        "events": [list(e) for e in res.events],
        "tasks": [[tid, rel, [v for loc in errands for v in divmod(loc, width)]]
                  for tid, rel, errands in res.tasks],
        "delayIntervals": [[list(i) for i in per] for per in res.delay_intervals],
        "assignmentWait": wait_percentiles(res.waits),
        "numPlannerErrors": 0,
        "numScheduleErrors": 0,
        "numEntryTimeouts": 0,
    }


def tasks_per_tick(res: LifelongResult) -> float:
    """Throughput: finished tasks per tick."""
    return res.finished / res.ticks if res.ticks else 0.0


def mean(values: Sequence[float]) -> float:
    """Arithmetic mean (0 for none)."""
    return sum(values) / len(values) if values else 0.0
