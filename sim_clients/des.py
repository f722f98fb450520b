"""Driver 3 of DESIGN section 1: a discrete-event simulation in virtual time.

:func:`run_simulation` executes one plan with the real :class:`~gateway.execution.oneshot.executor.
Executor`, simulated robots (:mod:`sim_clients.robot`) on a :class:`~sim_clients.world.World`
and optionally the intruder (:mod:`sim_clients.intruder`). Time jumps from event to event on a
heap; the executor is ticked at every multiple of ``MONITOR_PERIOD_MS``. Events at one instant
run in a fixed order (arrivals, then blocked robots looking again, the intruder, a finished
solver -- a shadow solve's too: the fleet runs on while it solves --, a policy wake-up, the
monitor tick), so a run is a function of its configuration and
seed, except for the solver's CPU time when ``solver_time="measured"``.
"""

from __future__ import annotations

import copy
import dataclasses
import heapq
import random
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Self

from gateway.execution.actions import ActionDurations
from gateway.execution.commands import (
    Cancel,
    Completed,
    Dispatch,
    PlanAdopted,
    Rescheduled,
    SolveRequest,
    Trigger,
)
from gateway.execution.oneshot.executor import MONITOR_PERIOD_MS, Executor
from gateway.execution.oneshot.policies import (
    AUTONOMOUS_POLICIES,
    PolicyName,
    ReplanPolicy,
    make_policy,
)
from gateway.execution.params import PAPER
from gateway.execution.trace_records import TraceSink, intruder_record, summary_record
from gateway.planning.grid import Cell, Grid
from gateway.planning.plan import NoSolution, Plan
from gateway.planning.seeds import run_seed
from gateway.planning.solver import Place, solve
from gateway.runtime.deadline import WallDeadline
from gateway.runtime.solver_time import SolverTime, run_charged
from sim_clients.intruder import Intruder, IntruderConfig, IntruderState, pick_target_at
from sim_clients.robot import RobotEvent, RobotState, SimRobot
from sim_clients.stays import StaySpec
from sim_clients.summary import RunSummary
from sim_clients.world import INTRUDER, World

ExtraDelay = Callable[[int, int, int], float]
"""``(plan, robot, action) -> extra ms`` added to an action's duration (delay injection)."""

# Order of events at one instant (lower first).
_ARRIVE, _RECHECK, _INTRUDER, _SOLVED, _POLICY = range(5)
_SHADOW = -2
"""The ``who`` of a shadow solve's ``_SOLVED`` event."""


class SimulationError(RuntimeError):
    """The simulation made no progress within its time bound (a deadlock)."""


def parse_solver_time(text: str) -> SolverTime:
    """``"measured"``, ``"zero"`` or a non-negative number of ms; ValueError otherwise."""
    if text == "measured":
        return "measured"
    if text == "zero":
        return "zero"
    try:
        value = float(text)
    except ValueError:
        raise ValueError(f"solver time must be 'measured', 'zero' or ms, got {text!r}") from None
    if not value >= 0 or value == float("inf"):
        raise ValueError(f"solver time must be a finite number of ms >= 0, got {text!r}")
    return value


@dataclass(frozen=True)
class SimConfig:
    """One simulated execution of ``plan`` on ``grid`` (replans solve on ``grid`` too)."""

    grid: Grid
    plan: Plan
    seed: int = 0
    intruder: bool = True
    policy: PolicyName = "none"
    threshold_ms: float = PAPER.threshold_ms
    solver_time: SolverTime = "measured"
    solver_time_limit_s: float = 30.0
    trace: TraceSink | None = None
    intruder_config: IntruderConfig = field(default_factory=IntruderConfig)
    intruder_stay: StaySpec | None = None
    """The intruder's stay after its robot needs the cell, drawn from the run's seed (None:
    ``intruder_config`` says when it leaves, by default the paper's ``T_d``)."""
    action_ms: float = PAPER.action_ms
    durations: ActionDurations | None = None
    """Duration of each action kind (move, turn, wait); by default each takes ``action_ms``.
    The simulated robots take exactly what the executor expects (plus ``extra_delay``)."""
    extra_delay: ExtraDelay | None = None
    max_replans: int = PAPER.max_replans
    lookahead: int = 0
    """Actions the executor may queue on a robot beyond its current one (see Executor)."""
    informed: bool = False
    """Informed replanning: a replan keeps the robots off the cells the fleet reported blocked
    until each block's estimated end (:mod:`gateway.execution.oneshot.blocks`)."""
    block_history: tuple[float, ...] = ()
    """How long the blocks the fleet saw before this run lasted (ms): what the block
    estimates start from (:mod:`gateway.execution.oneshot.blocks`)."""
    stall_ms: float = 600_000.0
    """Give up (SimulationError) this long after the last robot finished or started an action."""

    def __post_init__(self) -> None:
        if self.policy not in AUTONOMOUS_POLICIES:
            raise ValueError(f"policy must be one of {AUTONOMOUS_POLICIES}, got {self.policy!r}")
        if isinstance(self.solver_time, str):
            parse_solver_time(self.solver_time)
        elif not 0 <= self.solver_time < float("inf"):
            raise ValueError(f"solver_time must be finite and >= 0 ms, got {self.solver_time}")
        if self.threshold_ms < 0 or self.action_ms <= 0 or self.stall_ms <= 0:
            raise ValueError("threshold_ms must be >= 0, action_ms and stall_ms > 0")
        if self.lookahead < 0:
            raise ValueError(f"lookahead must be >= 0, got {self.lookahead}")
        if len(self.plan.paths) == 0:
            raise ValueError("the plan has no robots")
        for k, path in enumerate(self.plan.paths):
            bad = next((c for c in path if not self.grid.is_free(c)), None)
            if bad is not None:
                raise ValueError(f"robot {k}'s path visits {bad}, not a free cell of "
                                 f"{self.grid!r}")


@dataclass(frozen=True)
class SimResult(RunSummary):
    """What one simulated execution measured (times in ms of virtual time): the run summary
    and more."""

    plan_makespan: int
    robot_blocks: int
    """Times a robot found its next cell held by another robot (the ADG should prevent it)."""
    intruder_robot: int | None
    """The robot the intruder went for (None if it had no target)."""
    intruder_cell: Cell | None
    intruder_on_ms: float | None
    """When the intruder entered its cell; None if it never did."""
    end_ms: float
    reschedules: int = 0
    """Times the policy switched Type 2 edges (reschedule-first)."""
    reschedule_at_ms: float | None = None
    """When it first did; None if it never did."""
    blocks_ms: tuple[float, ...] = ()
    """How long each block the fleet reported in this run lasted, in the order they cleared:
    what the executor's block tracker learned from the robots' reports (a block's duration is
    from the first report to the cell being free again), not the simulator's ground truth."""


def policy_for(config: SimConfig) -> ReplanPolicy:
    """The executor's replanning policy for ``config`` (its own seed, derived from the run's)."""
    return make_policy(config.policy, seed=run_seed(config.seed, "replan"),
                       threshold_ms=config.threshold_ms,
                       makespan_lb_ms=config.plan.makespan * config.action_ms,
                       intruder_appear_ms=config.intruder_config.appear_ms)


def intruder_config(config: SimConfig) -> IntruderConfig:
    """The intruder of ``config``, its stay drawn from the run's seed if it has one."""
    if config.intruder_stay is None:
        return config.intruder_config
    return dataclasses.replace(config.intruder_config,
                               stay_ms=config.intruder_stay.draw_ms(config.seed))


def run_simulation(config: SimConfig) -> SimResult:
    """Execute ``config.plan`` in virtual time and return the measurements."""
    return Simulation(config).run()


class Simulation:
    """State of one run: :meth:`run` is the whole event loop; :meth:`start`,
    :meth:`run_until`, :meth:`fork` and :meth:`replan_now` let a caller stop a run at a time,
    copy it and replan in the copy (the oracle's sweep, :mod:`experiments.oracle`)."""

    def __init__(self, config: SimConfig) -> None:
        self.cfg = config
        plan = config.plan
        starts = [p[0] for p in plan.paths]
        self.world = World(starts)
        self.robots = [SimRobot(k, self.world, cell,
                                heading=None if plan.headings is None else plan.headings[k][0])
                       for k, cell in enumerate(starts)]
        self.executor = Executor(plan, policy=policy_for(config),
                                 action_ms=config.action_ms, max_replans=config.max_replans,
                                 record=config.trace, lookahead=config.lookahead,
                                 durations=config.durations, informed=config.informed,
                                 block_history=config.block_history)
        self.intruder = Intruder(self.world, intruder_config(config)) if config.intruder \
            else None
        self.rng = random.Random(run_seed(config.seed, "intruder"))
        self.heap: list[tuple[float, int, int, int]] = []
        self.seq = 0
        self.robot_wake: list[float | None] = [None] * len(starts)
        self.policy_wake: float | None = None
        self.next_action = [0] * len(starts)
        self.pending_plan: Plan | None = None
        self.shadow_plan: Plan | None = None
        self.shadow_memo: dict[tuple[object, ...], tuple[Plan | None, float]] = {}
        """Shadow solves by request: the same request gives the same plan (and charge)."""
        self.shadow_solves = 0
        self.replans = 0
        self.replan_at: float | None = None
        self.reschedules = 0
        self.reschedule_at: float | None = None
        self.solver_ms = 0.0
        self.robot_blocks = 0
        self.last_progress = 0.0
        self.completed: Completed | None = None
        self.now = 0.0
        self.next_tick = 0.0

    def push(self, t: float, kind: int, who: int) -> None:
        self.seq += 1
        heapq.heappush(self.heap, (t, kind, self.seq, who))

    def run(self) -> SimResult:
        """The whole run, from the start to the last robot's last action."""
        self.start()
        self.run_until(None)
        return self.result()

    def start(self) -> None:
        """Time 0: the first plan is adopted and dispatched, the intruder scheduled."""
        self.executor.start(0.0)
        self.handle(0.0)
        if self.intruder is not None:
            self.push(self.cfg.intruder_config.appear_ms, _INTRUDER, INTRUDER)

    def finished(self) -> bool:
        """True once the run has nothing more to do."""
        return self.completed is not None

    def run_until(self, until_ms: float | None) -> None:
        """Process events until the run is finished or, given ``until_ms``, until every event
        that comes before a policy decision at ``until_ms`` is done (so a replan decided then
        sees the same state as a policy firing at ``until_ms`` would)."""
        ex = self.executor
        heap = self.heap
        while not self.finished():
            if heap and heap[0][0] <= self.next_tick:
                if until_ms is not None and heap[0][:2] >= (until_ms, _POLICY):
                    return
                self.now, kind, _, who = heapq.heappop(heap)
                now = self.now
                if kind <= _RECHECK:
                    self.wake_robot(who, now)
                elif kind == _INTRUDER:
                    self.wake_intruder(now)
                elif kind == _SOLVED:
                    if who == _SHADOW:
                        self.shadow_solved(now)
                    else:
                        self.solved(now)
                elif now == self.policy_wake:
                    self.policy_wake = None
                    ex.tick(now)
                    self.handle(now)
            else:
                if until_ms is not None and self.next_tick >= until_ms:
                    return
                now = self.now = self.next_tick
                self.next_tick += MONITOR_PERIOD_MS
                if now - self.last_progress > self.cfg.stall_ms:
                    raise SimulationError(f"no robot moved for {self.cfg.stall_ms:.0f} ms "
                                          f"before {now:.0f} ms: deadlock")
                ex.tick(now)
                self.handle(now)

    def fork(self, share: Sequence[object] = ()) -> Self:
        """An independent copy of the run as it stands. What never changes is shared (the
        configuration, the current plan and its ADG), and so are the objects of ``share``;
        the copied monitor views its own flat arrays (``Monitor.__getstate__``)."""
        ex = self.executor
        shared = {id(o): o for o in (self.cfg, ex.plan, ex.adg, *share)}
        return copy.deepcopy(self, shared)

    def replan_now(self, now_ms: float) -> None:
        """Decide a replan at ``now_ms`` (an operator's "replan now"), as if a policy fired;
        call after :meth:`run_until` ``(now_ms)``."""
        self.now = now_ms
        self.executor.request_replan(now_ms)
        self.handle(now_ms)

    def result(self) -> SimResult:
        """The measurements of a finished run."""
        assert self.completed is not None, "the run has not finished"
        if self.cfg.trace is not None:
            self.cfg.trace(summary_record(self.completed.soc_ms, self.completed.makespan_ms))
        intr = self.intruder
        return SimResult(
            soc_ms=self.completed.soc_ms, makespan_ms=self.completed.makespan_ms,
            plan_soc=self.cfg.plan.soc, plan_makespan=self.cfg.plan.makespan,
            replans=self.replans, replan_at_ms=self.replan_at, solver_ms=self.solver_ms,
            collisions=len(self.world.collisions), robot_blocks=self.robot_blocks,
            intruder_robot=intr.robot if intr is not None else None,
            intruder_cell=intr.cell if intr is not None and intr.entered_ms is not None
            else None,
            intruder_on_ms=intr.entered_ms if intr is not None else None, end_ms=self.now,
            reschedules=self.reschedules, reschedule_at_ms=self.reschedule_at,
            blocks_ms=tuple(self.executor.blocks.history[len(self.cfg.block_history):]))

    def wake_robot(self, k: int, now: float) -> None:
        if self.robot_wake[k] != now:
            return  # superseded by a cancel or a newer schedule
        self.robot_wake[k] = None
        self.robot_events(self.robots[k].wake(now))
        self.schedule_robot(k)
        self.handle(now)

    def schedule_robot(self, k: int) -> None:
        robot = self.robots[k]
        t = robot.next_wakeup_ms()
        if t is not None and t != self.robot_wake[k]:
            self.robot_wake[k] = t
            self.push(t, _ARRIVE if robot.state is RobotState.MOVING else _RECHECK, k)

    def robot_events(self, events: list[RobotEvent]) -> None:
        ex = self.executor
        for e in events:
            if e.kind == "started":
                if e.plan == ex.plan_id:
                    self.next_action[e.robot] = e.action + 1
                self.last_progress = e.t_ms
                ex.started(e.robot, e.plan, e.action, e.t_ms)
            elif e.kind == "finished":
                self.last_progress = e.t_ms
                ex.finished(e.robot, e.plan, e.action, e.t_ms)
            elif e.kind == "blocked":
                d = self.robots[e.robot].current
                assert d is not None
                if INTRUDER not in self.world.holders(d.dst):
                    self.robot_blocks += 1
                ex.blocked(e.robot, e.plan, e.action, e.t_ms)
            elif e.kind == "unblocked":
                ex.unblocked(e.robot, e.plan, e.action, e.t_ms)
            else:
                ex.cancelled(e.robot, e.plan, e.action, e.t_ms)

    def handle(self, now: float) -> None:
        """Carry out the executor's commands until it has nothing more to say."""
        ex = self.executor
        cmds = ex.drain()
        while cmds:
            for c in cmds:
                if isinstance(c, Dispatch):
                    extra = self.cfg.extra_delay(c.plan, c.robot, c.action) \
                        if self.cfg.extra_delay is not None else 0.0
                    self.robot_events(self.robots[c.robot].dispatch(c, now, extra))
                    self.schedule_robot(c.robot)
                elif isinstance(c, Cancel):
                    self.robot_events(self.robots[c.robot].cancel(c.plan, c.action, now))
                    if self.robots[c.robot].next_wakeup_ms() is None:
                        self.robot_wake[c.robot] = None
                elif isinstance(c, Trigger):
                    if self.replan_at is None:
                        self.replan_at = now
                elif isinstance(c, Rescheduled):
                    self.reschedules += 1
                    if self.reschedule_at is None:
                        self.reschedule_at = now
                elif isinstance(c, SolveRequest):
                    if c.shadow:
                        self.shadow_solve(c, now)
                    else:
                        self.solve(c, now)
                elif isinstance(c, PlanAdopted):
                    if c.plan > 0:
                        self.replans += 1
                    self.next_action = [0] * len(self.robots)
                elif isinstance(c, Completed):
                    self.completed = c
            cmds = ex.drain()
        wake = ex.next_wakeup_ms()
        if wake is not None and wake >= now and wake != self.policy_wake:
            self.policy_wake = wake
            self.push(wake, _POLICY, -1)

    def solve(self, request: SolveRequest, now: float) -> None:
        self.pending_plan, charged = self.plan_for(request, now)
        self.solver_ms += charged
        self.last_progress = now + charged
        self.push(now + charged, _SOLVED, -1)

    def shadow_solve(self, request: SolveRequest, now: float) -> None:
        """Solve in the background: the plan comes back to the executor after the solver's
        charged time, while the fleet runs on."""
        key = (request.starts, request.headings, request.obstacles, request.start_ms)
        got = self.shadow_memo.get(key)
        if got is None:
            got = self.shadow_memo[key] = self.plan_for(request, now)
            self.shadow_solves += 1
        self.shadow_plan = got[0]
        self.push(now + got[1], _SOLVED, _SHADOW)

    def shadow_solved(self, now: float) -> None:
        plan, self.shadow_plan = self.shadow_plan, None
        self.executor.shadow_solved(plan, now)
        self.handle(now)

    def plan_for(self, request: SolveRequest, now: float) -> tuple[Plan | None, float]:
        """Solve ``request`` at ``now`` (None: no plan in time) and the virtual ms it is
        charged. A reported block is forbidden from the plan's first timestep until the
        first one that starts at or after its expected end (counted from the request's
        ``start_ms`` if given)."""
        hs = request.headings
        forbidden = request.forbidden(now, self.cfg.action_ms)
        starts: tuple[Place, ...] = request.starts if hs is None else tuple(
            (x, y, h) for (x, y), h in zip(request.starts, hs, strict=True))

        def plan() -> Plan | None:
            try:
                return solve(self.cfg.grid, starts, request.goals,
                             deadline=WallDeadline(self.cfg.solver_time_limit_s),
                             forbidden=forbidden,
                             motion="omni" if hs is None else "turning").plan
            except NoSolution:
                return None

        return run_charged(plan, self.cfg.solver_time)

    def solved(self, now: float) -> None:
        if self.pending_plan is None:
            self.executor.abandon_replan(now)
        else:
            self.executor.adopt_plan(self.pending_plan, now)
        self.pending_plan = None
        self.handle(now)

    def wake_intruder(self, now: float) -> None:
        intr = self.intruder
        assert intr is not None
        if intr.state is IntruderState.ABSENT:
            ex = self.executor
            visit = ex.monitor.start_ms if intr.config.reading == "start" else \
                ex.monitor.completion_ms
            target = pick_target_at(self.rng, ex.plan.paths, self.next_action, visit,
                                    now + intr.config.lead_ms)
            events = intr.appear(now, None if target is None else target[:2],
                                 None if target is None else target[2])
        else:
            events = intr.wake(now)
        if self.cfg.trace is not None:
            for e in events:
                self.cfg.trace(intruder_record(e.t_ms, e.cell, e.state))
        t = intr.next_wakeup_ms()
        if t is not None:
            self.push(t, _INTRUDER, INTRUDER)
