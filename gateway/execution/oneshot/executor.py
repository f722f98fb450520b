"""The retiming executor and its replanning state machine (DESIGN section 2), sans-I/O.

Drivers feed robot events with the current time and take commands from :meth:`Executor.drain`.
With ``lookahead=0`` (classic retiming) an action is dispatched only when all its incoming ADG
edges are done. A replan goes
RUNNING -> STOPPING (no new dispatches; running actions finish; dispatched, unstarted ones are
cancelled, and so is a move stopped on the way by an obstacle -- a ``blocked`` after its
``started``, a TurtleBot's bumper contact: :meth:`Executor.stopped` -- whose robot then goes
back to its source cell) -> SOLVING (``SolveRequest`` emitted once every robot is idle) ->
RUNNING (after ``adopt_plan`` with plan id + 1, or ``abandon_replan`` which resumes the old
plan).

Shadow planning (a policy with ``shadow``, :mod:`gateway.execution.oneshot.shadow`): while RUNNING,
a
``SolveRequest(shadow=True)`` asks for a plan from where the robots would stop; the fleet runs
on, and the driver answers with :meth:`Executor.shadow_solved`. If the robots would still stop
there and the estimate says the plan pays, the replan is decided then (a ``Trigger``) and the
plan is adopted as soon as the robots are idle, with no ``SolveRequest``; otherwise nothing
happens. Only a decided replan counts against the budget.

A robot may refuse a dispatched action it has not started (:meth:`Executor.refused`, e.g. it
does not start where the robot stands): the action and the robot's later dispatched ones are
taken back, not executed, and the robot gets nothing more of the plan until a replan (adopted
or abandoned) -- its slack grows, which a slack policy answers with a replan.

Replan budget: every decided replan counts against ``max_replans``, whoever decided it (policy or
operator) and whether or not a plan was then adopted.

Lookahead dispatch (``lookahead=N > 0``, pipelining as a VDA 5050 order releases the part a robot
may drive): besides the action a robot runs or waits for, up to ``N`` further actions of the same
robot may be dispatched (queued on the robot). Action ``a_{i+1}`` of robot k is released as soon
as (1) every incoming Type 2 edge of ``a_{i+1}`` is done and (2) ``a_i`` is dispatched to robot k
(queued, running or finished), and the robot holds fewer than ``1 + N`` unfinished actions.

Safety: the ADG guarantee is about when an action STARTS, not when it is dispatched. An action's
incoming edges are its Type 2 edges and the Type 1 edge from its predecessor. (1) makes every
Type 2 edge done before dispatch, so before the start; done edges never become undone within a
plan. The Type 1 edge is enforced by the robot itself: the protocol requires a robot to execute
its actions strictly in the order of their index and to start ``a_{i+1}`` only after finishing
``a_i``, and this executor refuses (``ExecutionError``) a ``started`` (or ``blocked``,
``unblocked``, ``finished``) of any action but the first unfinished one of the robot's queue, or
of an action whose predecessor has not finished. So at every accepted start all incoming edges
are done, exactly as with classic retiming; the monitor only learns starts and finishes, so its
estimates do not depend on the lookahead. Replanning cancels queued actions like blocked ones
(none of them has started), and ``SolveRequest`` waits until every queue is empty.
"""

from __future__ import annotations

import enum
import math
from collections import deque
from collections.abc import Sequence
from typing import TYPE_CHECKING

from gateway.execution.actions import ActionDurations, per_robot
from gateway.execution.commands import (
    Cancel,
    Command,
    Completed,
    Dispatch,
    PlanAdopted,
    Rescheduled,
    SolveRequest,
    Trigger,
)
from gateway.execution.core import MONITOR_PERIOD_MS, check_robot, check_start, check_time
from gateway.execution.errors import ExecutionError
from gateway.execution.oneshot.adg import ADG, gated_waits
from gateway.execution.oneshot.blocks import BlockTracker
from gateway.execution.oneshot.monitor import Monitor
from gateway.execution.oneshot.policies import NoReplan, ReplanPolicy, Rescheduling, ShadowPolicy
from gateway.execution.oneshot.reschedule import Schedule, Search, improve
from gateway.execution.oneshot.shadow import candidate_monitor, forecast_completions
from gateway.execution.params import PAPER
from gateway.execution.trace_records import (
    TraceSink,
    event_record,
    plan_record,
    reschedule_record,
    trigger_record,
)
from gateway.planning.grid import Cell
from gateway.planning.plan import Plan

if TYPE_CHECKING:
    import numpy as np
    import numpy.typing as npt

__all__ = ["MONITOR_PERIOD_MS", "ExecutionError", "Executor", "Mode"]

_PENDING, _DISPATCHED, _STARTED, _DONE = 0, 1, 2, 3


class Mode(enum.Enum):
    """Where the executor is in its life and in the replanning state machine."""

    NEW = "new"  # before start()
    RUNNING = "running"
    STOPPING = "stopping"  # replan decided, waiting for robots to become idle
    SOLVING = "solving"  # SolveRequest emitted, waiting for adopt_plan / abandon_replan
    DONE = "done"


class Executor:
    """Executes a plan on a fleet through its ADG: retiming, monitoring, replanning.

    A ``turning`` plan (with ``plan.headings``) makes turns actions of their own.
    ``durations`` is the expected duration of each action kind, for every robot or per robot
    (its model); by default every action takes ``action_ms``.
    """

    def __init__(self, plan: Plan, *, policy: ReplanPolicy | None = None,
                 action_ms: float = PAPER.action_ms, drop_waits: bool = False,
                 max_replans: int = PAPER.max_replans, record: TraceSink | None = None,
                 lookahead: int = 0,
                 durations: ActionDurations | Sequence[ActionDurations] | None = None,
                 informed: bool = False, block_history: Sequence[float] = ()) -> None:
        if not (math.isfinite(action_ms) and action_ms > 0):
            raise ExecutionError(f"action_ms must be a positive number, got {action_ms}")
        if max_replans < 0:
            raise ExecutionError(f"max_replans must be >= 0, got {max_replans}")
        if lookahead < 0:
            raise ExecutionError(f"lookahead must be >= 0, got {lookahead}")
        self.lookahead = lookahead
        self._informed = informed
        self.blocks = BlockTracker(min_ms=action_ms, history=list(block_history))
        """Cells robots wait for that no robot is planned to hold (kept across plans), and
        how long earlier blocks lasted (``block_history``: seen before this run)."""
        self.policy: ReplanPolicy = policy if policy is not None else NoReplan()
        self.drop_waits = drop_waits
        self.max_replans = max_replans
        self.replans = 0
        self.paused = False
        """Between :meth:`pause` and :meth:`resume`: the monitor is kept up to date at every
        tick, but the policy is not asked."""
        self._growth_at_pause: npt.NDArray[np.float64] | None = None
        self.mode = Mode.NEW
        self._record = record
        self._out: list[Command] = []
        self._now = 0.0
        adg = ADG(plan, drop_waits=drop_waits)
        self.durations = per_robot(
            ActionDurations.uniform(action_ms) if durations is None else durations, adg.n_robots)
        self._goals: tuple[Cell, ...] = tuple(p[-1] for p in plan.paths)
        self._cells: list[Cell] = [p[0] for p in plan.paths]
        self._headings: list[int] | None = None if adg.headings is None else \
            [h[0] for h in adg.headings]
        self._completion = [0.0] * adg.n_robots
        self._shadow: tuple[tuple[Cell, ...], tuple[int, ...] | None] | None = None
        """The stop configuration an outstanding shadow solve plans from."""
        self._next_shadow_ms = 0.0
        self._ready: Plan | None = None
        """A shadow plan to adopt once the decided stop is complete."""
        self._install(plan, adg, 0, 0.0)

    def _install(self, plan: Plan, adg: ADG, plan_id: int, now_ms: float) -> None:
        """Make ``plan`` the current one (nothing dispatched yet)."""
        self.plan, self.plan_id, self.adg = plan, plan_id, adg
        tx = [self.durations[adg.robot_of[v]].of(adg.kind[v]) for v in range(adg.n_vertices)]
        self.monitor = Monitor(adg, now_ms=now_ms, action_ms=tx,
                               base_completion_ms=self._completion)
        self._schedule: Schedule | None = None  # the visit order, built at the first reschedule
        self._status = bytearray(adg.n_vertices)
        self._blocked = bytearray(adg.n_vertices)
        self._cancelling = bytearray(adg.n_vertices)
        # per robot: its dispatched, not finished (nor cancelled) vertices, in index order
        self._queue: list[deque[int]] = [deque() for _ in range(adg.n_robots)]
        self._refusing = bytearray(adg.n_robots)  # refused an action: dispatch it nothing
        self._busy = 0  # vertices in all queues
        self._left = adg.n_vertices
        if self.paused:  # a plan adopted during a pause: its slack counts from now
            self._growth_at_pause = self.monitor.growth()

    # ------------------------------------------------------------------ queries
    @property
    def informed(self) -> bool:
        """Informed replanning: a ``SolveRequest`` carries the reported blocks as obstacles
        (asked for at construction, or by the policy)."""
        return self._informed or self.policy.informed

    @property
    def shadow_pending(self) -> bool:
        """True while a shadow solve is outstanding (``shadow_solved`` expected)."""
        return self._shadow is not None

    @property
    def done(self) -> bool:
        """True once every robot has finished its last action."""
        return self.mode is Mode.DONE

    @property
    def soc_ms(self) -> float:
        """Sum over robots of their last completion time so far (final when done)."""
        return sum(self._completion)

    @property
    def makespan_ms(self) -> float:
        """Largest completion time so far (final when done)."""
        return max(self._completion, default=0.0)

    @property
    def completions_ms(self) -> tuple[float, ...]:
        """Each robot's last completion time so far (its SOC term)."""
        return tuple(self._completion)

    @property
    def now_ms(self) -> float:
        """Time of the latest accepted input."""
        return self._now

    def robot_cell(self, robot: int) -> Cell:
        """The cell the robot stands on (until a running move finishes), its goal at the end."""
        self._check_robot(robot)
        return self._cells[robot]

    def robot_heading(self, robot: int) -> int | None:
        """The robot's heading (turning motion model; None under ``omni``), as of its last
        finished action."""
        self._check_robot(robot)
        return None if self._headings is None else self._headings[robot]

    def has_started(self, robot: int, plan: int, action: int) -> bool:
        """True if ``a_action^robot`` of the current plan ``plan`` started (or finished)."""
        self._check_robot(robot)
        if plan != self.plan_id:
            return False
        return self._status[self.adg.vertex(robot, action)] in (_STARTED, _DONE)

    def completion_ms(self, robot: int) -> float:
        """Finish time of the robot's latest action (0 if it has none)."""
        self._check_robot(robot)
        return self._completion[robot]

    def next_wakeup_ms(self) -> float | None:
        """Earliest time a time-based policy wants ``tick()`` (None if none)."""
        if self.mode is Mode.RUNNING and self.replans < self.max_replans and not self.paused:
            return self.policy.next_wakeup_ms()
        return None

    def drain(self) -> list[Command]:
        """The commands emitted since the last call, in order."""
        out, self._out = self._out, []
        return out

    # ------------------------------------------------------------------ checks
    def _check_time(self, now_ms: float) -> None:
        check_time(now_ms, self._now, self.mode is not Mode.NEW, "execution")

    def _check_robot(self, robot: int) -> None:
        check_robot(robot, self.adg.n_robots)

    def _event_vertex(self, kind: str, robot: int, plan: int, action: int, now_ms: float) -> int:
        """Validate the common part of a robot event; return the action's vertex."""
        self._check_time(now_ms)
        self._check_robot(robot)
        if plan != self.plan_id:
            raise ExecutionError(
                f"{kind} of robot {robot} action {action} refers to plan {plan}, "
                f"but plan {self.plan_id} is being executed"
            )
        v = self.adg.vertex(robot, action)
        queue = self._queue[robot]
        if queue and queue[0] == v:
            return v  # (the usual case: the robot's current action)
        if v not in queue:
            state = ("finished" if self._status[v] == _DONE else "not dispatched")
            raise ExecutionError(
                f"{kind} of robot {robot} action {action} (plan {plan}): that action is {state}"
            )
        if kind not in ("cancelled", "refused") and v != queue[0]:
            raise ExecutionError(
                f"{kind} of robot {robot} action {action} (plan {plan}): it is queued behind "
                f"action {self.adg.step_of[queue[0]]}, which has not finished"
            )
        return v

    def _expect(self, ok: bool, kind: str, robot: int, action: int, why: str) -> None:
        if not ok:
            raise ExecutionError(f"{kind} of robot {robot} action {action}: {why}")

    # ------------------------------------------------------------------ robot events
    def start(self, now_ms: float) -> None:
        """Begin execution: emit ``PlanAdopted(0, plan)`` and the first dispatches."""
        check_start(now_ms, self.mode is not Mode.NEW)
        self.mode = Mode.RUNNING
        self._now = now_ms  # kept as given (trace t_ms)
        if now_ms != 0.0:
            self._install(self.plan, self.adg, 0, self._now)
        self._adopted()

    def start_adopted(self, plan_id: int, now_ms: float, *, completions_ms: Sequence[float],
                      replans: int, paused: bool) -> None:
        """Begin execution where a run stood when it adopted this executor's plan as plan
        ``plan_id`` at ``now_ms``: each robot's latest completion time, the replans decided
        and the pause of that moment (a journal's snapshot; the caller restores ``blocks``
        and ``policy``). What follows is what :meth:`adopt_plan` does then."""
        if self.mode is not Mode.NEW:
            raise ExecutionError("start() was already called")
        if len(completions_ms) != self.adg.n_robots:
            raise ExecutionError(f"{len(completions_ms)} completion times for "
                                 f"{self.adg.n_robots} robots")
        self.mode = Mode.RUNNING
        self._now = now_ms  # kept as given (trace t_ms)
        self._completion = [float(c) for c in completions_ms]
        self.replans, self.paused = replans, paused
        self._install(self.plan, self._adg_of(self.plan) if plan_id else self.adg, plan_id,
                      now_ms)
        self._adopted()

    def started(self, robot: int, plan: int, action: int, now_ms: float) -> None:
        """The robot began to move (after any wait for its target cell)."""
        v = self._event_vertex("start", robot, plan, action, now_ms)
        self._expect(self._status[v] == _DISPATCHED, "start", robot, action, "already started")
        p = self.adg.t1_pred(v)
        if p >= 0 and self._status[p] != _DONE:
            self._expect(False, "start", robot, action,
                         f"its predecessor action {self.adg.step_of[p]} has not finished")
        self._advance(now_ms)
        self._status[v] = _STARTED
        self._blocked[v] = self._cancelling[v] = 0
        if self.adg.src[v] != self.adg.dst[v]:
            self.blocks.cleared(self.adg.dst[v], now_ms)  # a robot got in: the block is gone
        self.monitor.action_started(v, now_ms)
        self._trace("start", robot, action)

    def finished(self, robot: int, plan: int, action: int, now_ms: float) -> None:
        """The robot arrived at the action's target cell."""
        v = self._event_vertex("finish", robot, plan, action, now_ms)
        self._expect(self._status[v] == _STARTED, "finish", robot, action,
                     "it has not started (no start reported)")
        self._advance(now_ms)
        self._status[v] = _DONE
        self._queue[robot].popleft()
        self._busy -= 1
        self._left -= 1
        self._cells[robot] = self.adg.dst[v]
        if self._headings is not None and self.adg.headings is not None:
            self._headings[robot] = self.adg.headings[robot][self.adg.step_of[v] + 1]
        self._completion[robot] = self._now
        self.monitor.action_finished(v, now_ms)
        self._trace("finish", robot, action)
        if self.mode is Mode.RUNNING:
            adg = self.adg
            heads = adg.t2_succ[adg.t2_succ_ptr[v]:adg.t2_succ_ptr[v + 1]]
            for r in sorted({robot, *(adg.robot_of[w] for w in heads)}):
                self._fill(r)
            if self._left == 0:
                self._complete()
        elif self.mode is Mode.STOPPING:
            self._maybe_solve()

    def blocked(self, robot: int, plan: int, action: int, now_ms: float) -> None:
        """The robot found the action's target cell taken and waits."""
        v = self._event_vertex("blocked", robot, plan, action, now_ms)
        self._expect(self._status[v] == _DISPATCHED, "blocked", robot, action,
                     "it has already started (a move stopped on the way is stopped())")
        self._mark_blocked(v, robot, action, now_ms)

    def stopped(self, robot: int, plan: int, action: int, now_ms: float) -> None:
        """A move under way was stopped by an obstacle (a TurtleBot's bumper contact; the
        protocol's ``blocked`` after ``started``): a replan may cancel it, and the robot then
        goes back to the move's source cell; ``unblocked`` if it drives on."""
        v = self._event_vertex("blocked", robot, plan, action, now_ms)
        self._expect(self._status[v] == _STARTED and self.adg.kind[v] == "move", "blocked",
                     robot, action, "only a move under way can be stopped on the way")
        self._mark_blocked(v, robot, action, now_ms)

    def _mark_blocked(self, v: int, robot: int, action: int, now_ms: float) -> None:
        self._expect(not self._blocked[v], "blocked", robot, action, "it is already blocked")
        self._advance(now_ms)
        self._blocked[v] = 1
        cell = self.adg.dst[v]
        if not self._planned_occupant(cell, robot):
            self.blocks.opened(cell, now_ms)
        self._trace("blocked", robot, action)

    def _watch_blocks(self) -> None:
        """Every robot still waiting for a blocked cell sees it blocked now."""
        if not self.blocks.open:
            return
        for queue in self._queue:
            if queue and self._blocked[queue[0]]:
                self.blocks.still_blocked(self.adg.dst[queue[0]], self._now)

    def _planned_occupant(self, cell: Cell, robot: int) -> bool:
        """True if a robot other than ``robot`` stands on ``cell`` or is moving into it."""
        adg = self.adg
        for r in range(adg.n_robots):
            if r == robot:
                continue
            if self._cells[r] == cell:
                return True
            queue = self._queue[r]
            if queue and self._status[queue[0]] == _STARTED and adg.dst[queue[0]] == cell:
                return True
        return False

    def unblocked(self, robot: int, plan: int, action: int, now_ms: float) -> None:
        """The action's target cell became free again."""
        v = self._event_vertex("unblocked", robot, plan, action, now_ms)
        self._expect(self._status[v] in (_DISPATCHED, _STARTED) and bool(self._blocked[v]),
                     "unblocked", robot, action, "it is not blocked")
        self._advance(now_ms)
        self._blocked[v] = 0
        self.blocks.cleared(self.adg.dst[v], now_ms)
        self._trace("unblocked", robot, action)

    def cancelled(self, robot: int, plan: int, action: int, now_ms: float) -> None:
        """The robot confirms a ``Cancel``: it did not move, or (a move stopped on the way)
        went back, and stays on the action's source."""
        v = self._event_vertex("cancelled", robot, plan, action, now_ms)
        self._expect(self._status[v] in (_DISPATCHED, _STARTED) and bool(self._cancelling[v]),
                     "cancelled", robot, action, "no Cancel is outstanding for it")
        self._advance(now_ms)
        if self._blocked[v]:
            self.blocks.still_blocked(self.adg.dst[v], now_ms)
        if self._status[v] == _STARTED:
            self.monitor.action_cancelled(v)
        self._status[v] = _PENDING
        self._blocked[v] = self._cancelling[v] = 0
        self._queue[robot].remove(v)
        self._busy -= 1
        self._trace("cancel", robot, action)
        self._maybe_solve()

    def refused(self, robot: int, plan: int, action: int, now_ms: float,
                reason: str = "") -> None:
        """The robot will not execute the action (``reason``), which has not started: it and
        the robot's later dispatched actions go back to not dispatched (a ``refused`` trace
        record each, the first with the reason), and the robot gets no dispatch until a
        replan is adopted or abandoned."""
        v = self._event_vertex("refused", robot, plan, action, now_ms)
        self._expect(self._status[v] == _DISPATCHED, "refused", robot, action,
                     "it has already started")
        self._advance(now_ms)
        queue, back = self._queue[robot], []
        while queue and queue[-1] >= v:
            back.append(queue.pop())
        for u in reversed(back):
            self._status[u] = _PENDING
            self._blocked[u] = self._cancelling[u] = 0
            self._busy -= 1
            self._trace("refused", robot, self.adg.step_of[u], reason if u == v else None)
        self._refusing[robot] = 1
        self._maybe_solve()

    # ------------------------------------------------------------------ time and replanning
    def tick(self, now_ms: float) -> None:
        """The present moved on: update the monitor's clamping and ask the policy (unless
        paused)."""
        self._check_time(now_ms)
        self._advance(now_ms)
        self.monitor.advance(self._now)
        self._watch_blocks()
        if self.mode is not Mode.RUNNING or self.paused:
            return
        if isinstance(self.policy, Rescheduling) and \
                self.policy.should_reschedule(self._now, self.monitor):
            self._reschedule()
        if self.replans < self.max_replans:
            if self.policy.should_replan(self._now, self.monitor):
                self._trigger(self.policy.name)
            elif isinstance(self.policy, ShadowPolicy):
                self._maybe_shadow(self.policy)

    def reschedule(self, now_ms: float, search: Search = improve) -> bool:
        """Reschedule-first (:mod:`gateway.execution.oneshot.reschedule`): switch Type 2 edges of
        the
        current plan so that others pass a delayed robot, as ``search`` proposes (by default
        when the monitor's estimate says the fleet then finishes earlier). No robot stops:
        only actions not dispatched yet may get new dependencies. True if the schedule
        changed."""
        self._check_time(now_ms)
        if self.mode is not Mode.RUNNING:
            raise ExecutionError(f"cannot reschedule now: the executor is {self.mode.value}")
        self._advance(now_ms)
        self.monitor.advance(self._now)
        return self._reschedule(search)

    def _reschedule(self, search: Search = improve) -> bool:
        if self._schedule is None:
            self._schedule = Schedule.of(self.adg)
        status, adg = self._status, self.adg
        # What the fleet reported, for the estimate: a robot waiting for a blocked cell waits
        # until the block's expected end; an action running e ms late runs e ms more (the
        # blocks' scale-free rule, gateway.execution.oneshot.blocks)
        holds = {}
        for queue in self._queue:
            if not queue:
                continue
            v = queue[0]
            if status[v] == _DISPATCHED and self._blocked[v] and adg.dst[v] in self.blocks.open:
                holds[v] = self.blocks.expected_end_ms(adg.dst[v])
            elif status[v] == _STARTED:
                late = self._now - self.monitor.start_ms(adg.robot_of[v], adg.step_of[v]) \
                    - self.monitor.tx[v]
                if late > 0:
                    holds[v] = self._now + late
        found = search(self._schedule, adg, self.monitor, lambda v: status[v] == _PENDING,
                       holds)
        if found is None:
            return False
        self.adg, self.monitor, self._schedule = found.adg, found.monitor, found.schedule
        self._out.append(Rescheduled(found.switches, found.gain_ms))
        if self._record is not None:
            adg = self.adg
            self._record(reschedule_record(
                self._now, self.plan_id,
                [(adg.robot_of[t], adg.step_of[t], adg.robot_of[h], adg.step_of[h])
                 for t, h in adg.type2_pairs()],
                found.switches, found.gain_ms))
        self._dispatch_ready()
        return True

    def pause(self, now_ms: float) -> None:
        """The fleet stands still (running actions complete, no new one starts) until
        :meth:`resume`. Ticks keep the monitor's estimates and slack true meanwhile."""
        self._check_time(now_ms)
        if self.paused:
            raise ExecutionError("already paused")
        self._advance(now_ms)
        self.monitor.advance(self._now)
        self.paused = True
        self._growth_at_pause = self.monitor.growth()

    def resume(self, now_ms: float) -> None:
        """End of the pause. The slack growth the pause itself caused (every robot waited)
        is discounted: each action's Δ̄ is what it was when the pause began, plus nothing, so
        a block that cleared during the pause does not trigger a replan now; one that lasts
        makes the slack grow again from there."""
        self._check_time(now_ms)
        if not self.paused:
            raise ExecutionError("not paused")
        self._advance(now_ms)
        self.monitor.advance(self._now)
        assert self._growth_at_pause is not None
        self.monitor.keep_growth(self._growth_at_pause)
        self.paused = False
        self._growth_at_pause = None

    def request_replan(self, now_ms: float) -> None:
        """The operator's "replan now" (allowed with any policy, within ``max_replans``)."""
        self._check_time(now_ms)
        if self.mode is not Mode.RUNNING:
            raise ExecutionError(f"cannot replan now: the executor is {self.mode.value}")
        if self.replans >= self.max_replans:
            raise ExecutionError(
                f"cannot replan now: the budget of {self.max_replans} replan(s) is used up"
            )
        self._advance(now_ms)
        self.monitor.advance(self._now)
        self._trigger("operator")

    def shadow_solved(self, plan: Plan | None, now_ms: float) -> bool:
        """Answer to a ``SolveRequest(shadow=True)``: ``plan`` (None: no plan was found).
        Returns True if the replan is decided: the robots would still stop where the plan
        starts, the policy may replan and the plan is estimated to save at least the policy's
        margin; the plan is then adopted once the robots are idle. Otherwise nothing changes."""
        self._check_time(now_ms)
        if self._shadow is None:
            raise ExecutionError("no shadow solve is outstanding")
        self._advance(now_ms)
        planned, self._shadow = self._shadow, None
        policy = self.policy
        if (plan is None or not isinstance(policy, ShadowPolicy) or self.mode is not Mode.RUNNING
                or self.paused or self.replans >= self.max_replans):
            return False
        cells, headings, start = self._stop_config()
        if (cells, headings) != planned:
            self._next_shadow_ms = now_ms  # the fleet moved on: solve again at the next tick
            return False
        self._check_plan(plan, cells, headings)
        adg = self._adg_of(plan)
        evidence = min((self.blocks.evidence(c) for c in self.blocks.open), default=math.inf)
        if not policy.adopts(self._shadow_gains(adg, start, policy.levels), evidence):
            return False
        self._ready = plan
        self._trigger(policy.name)
        return True

    def _stop_config(self) -> tuple[tuple[Cell, ...], tuple[int, ...] | None, float]:
        """Where each robot would stand (and face) if the fleet stopped now -- on the target of
        the move it is making, else where it is -- and when the last of them gets there."""
        adg, cells = self.adg, list(self._cells)
        headings = None if self._headings is None else list(self._headings)
        end = self._now
        for r, queue in enumerate(self._queue):
            if queue and self._status[queue[0]] == _STARTED and not self._blocked[queue[0]]:
                v = queue[0]
                cells[r] = adg.dst[v]
                if headings is not None and adg.headings is not None:
                    headings[r] = adg.headings[r][adg.step_of[v] + 1]
                end = max(end, self.monitor.completion_ms(r, adg.step_of[v]))
        return tuple(cells), None if headings is None else tuple(headings), end

    def _shadow_gains(self, adg: ADG, start_ms: float,
                      levels: Sequence[float]) -> list[float]:
        """How much earlier (sum of completion times) the fleet is expected to finish if it
        stops and executes ``adg``'s plan from ``start_ms`` than if it keeps its plan, in one
        scenario per probability level of ``levels``: every open block ends at that quantile
        of its end (:meth:`BlockTracker.end_quantiles`; the blocks' ends comonotone), and in
        both forecasts every move into a blocked cell waits until then."""
        now, blocks, cur = self._now, self.blocks, self.adg
        ends = {c: blocks.end_quantiles(c, levels) for c in blocks.open}
        keep_moves: list[tuple[int, Cell]] = []
        completions = list(self._completion)
        for r, queue in enumerate(self._queue):
            v = self.monitor.next_vertex(r)
            if queue and self._status[queue[0]] == _STARTED:
                completions[r] = self.monitor.completion_ms(r, cur.step_of[queue[0]])
            if v < 0 or not ends:
                continue
            keep_moves += [(u, cur.dst[u]) for u in range(v, cur.first[r + 1])
                           if cur.dst[u] in ends and cur.src[u] != cur.dst[u]
                           and self._status[u] in (_PENDING, _DISPATCHED)]
        candidate = candidate_monitor(adg, self.durations, start_ms, completions)
        new_moves = [(u, adg.dst[u]) for u in range(adg.n_vertices)
                     if adg.dst[u] in ends and adg.src[u] != adg.dst[u]]
        gains = []
        for k in range(len(levels)):
            keep = forecast_completions(
                self.monitor, {u: ends[c][k] for u, c in keep_moves if ends[c][k] > now})
            new = forecast_completions(
                candidate, {u: ends[c][k] for u, c in new_moves if ends[c][k] > start_ms})
            gains.append(sum(keep) - sum(new))
        return gains

    def adopt_plan(self, plan: Plan, now_ms: float) -> None:
        """Answer to ``SolveRequest``: execute ``plan`` (from the robots' cells and, turning,
        their headings to the goals; a goal heading is free)."""
        self._check_time(now_ms)
        if self.mode is not Mode.SOLVING:
            raise ExecutionError(f"no plan was requested: the executor is {self.mode.value}")
        self._check_plan(plan)
        adg = self._adg_of(plan)
        self._advance(now_ms)
        self._adopt(plan, adg)

    def _adg_of(self, plan: Plan) -> ADG:
        """The ADG of a new plan. Informed, the plan was solved with the open blocks as
        obstacles until their expected ends: the waits it makes right before a move into a
        blocked cell are dropped (:func:`~gateway.execution.oneshot.adg.gated_waits`), so the
        robot moves in when the block really ends, not when it was expected to."""
        gated = gated_waits(plan, self.blocks.open) if self.informed else frozenset()
        return ADG(plan, drop_waits=self.drop_waits, gated=gated)

    def _check_plan(self, plan: Plan, cells: Sequence[Cell] | None = None,
                    headings: Sequence[int] | None = None) -> None:
        """A new plan must go from the robots' ``cells`` and ``headings`` (default: where they
        are) to their goals, for every robot, under the same motion model."""
        cells = self._cells if cells is None else cells
        held = self._headings if headings is None else headings
        n = self.adg.n_robots
        if len(plan.paths) != n:
            raise ExecutionError(f"the new plan has {len(plan.paths)} paths for {n} robots")
        if (plan.headings is None) != (held is None):
            raise ExecutionError("the new plan must have headings exactly when the current "
                                 "one has (the motion model cannot change)")
        if plan.headings is not None and held is not None:
            for r, hs in enumerate(plan.headings[:n]):
                if not hs or hs[0] != held[r]:
                    raise ExecutionError(f"robot {r}: the new path starts with heading "
                                         f"{hs[0] if hs else None}, but the robot holds "
                                         f"{held[r]}")
        for r, path in enumerate(plan.paths):
            if not path or path[0] != cells[r]:
                first = path[0] if path else None
                raise ExecutionError(
                    f"robot {r}: the new path starts at {first}, "
                    f"but the robot is at {cells[r]}"
                )
            if path[-1] != self._goals[r]:
                raise ExecutionError(
                    f"robot {r}: the new path ends at {path[-1]} but its goal is {self._goals[r]}"
                )

    def _fits(self, plan: Plan) -> bool:
        """True if ``plan`` starts where the robots are (a robot may have moved on after all:
        its cancel came too late)."""
        try:
            self._check_plan(plan)
        except ExecutionError:
            return False
        return True

    def _adopt(self, plan: Plan, adg: ADG) -> None:
        """Install ``plan`` (checked) as the next plan and dispatch it. A shadow solve still
        out is for the old plan: its answer is not expected any more (a journal's snapshot
        of the new plan starts without it)."""
        self._shadow, self._next_shadow_ms = None, 0.0
        self._install(plan, adg, self.plan_id + 1, self._now)
        self.mode = Mode.RUNNING
        self._adopted()

    def abandon_replan(self, now_ms: float) -> None:
        """The solver found no plan: resume the current one."""
        self._check_time(now_ms)
        if self.mode is not Mode.SOLVING:
            raise ExecutionError(f"no plan was requested: the executor is {self.mode.value}")
        self._advance(now_ms)
        self.mode = Mode.RUNNING
        self._refusing = bytearray(self.adg.n_robots)  # try the robots that refused again
        self._dispatch_ready()

    # ------------------------------------------------------------------ internals
    def _advance(self, now_ms: float) -> None:
        """Accept ``now_ms`` as the present (the monitor's clamping moves only at ticks)."""
        self._now = now_ms  # kept as given (trace t_ms)

    def _trace(self, kind: str, robot: int, action: int, reason: str | None = None) -> None:
        if self._record is not None:
            self._record(event_record(self._now, kind, self.plan_id, robot, action, reason))

    def _adopted(self) -> None:
        """Announce the current plan and dispatch what is ready."""
        adg = self.adg
        self._out.append(PlanAdopted(self.plan_id, self.plan))
        if self._record is not None:
            default = ActionDurations()
            self._record(plan_record(
                self._now, self.plan_id, self.plan.paths, adg.headings,
                [None if d == default else d.as_dict() for d in self.durations], adg.gated))
        self._dispatch_ready()

    def _dispatch_ready(self) -> None:
        """Dispatch what every robot may get now (robot order)."""
        for r in range(self.adg.n_robots):
            self._fill(r)
        if self._left == 0:
            self._complete()

    def _releasable(self, v: int) -> bool:
        """Every Type 2 edge into ``v`` is done, and its Type 1 predecessor is done, or (with
        lookahead) dispatched to the robot."""
        adg, status = self.adg, self._status
        p = adg.t1_pred(v)
        if p >= 0 and status[p] != _DONE and not (self.lookahead and status[p] != _PENDING):
            return False
        return all(status[u] == _DONE
                   for u in adg.t2_pred[adg.t2_pred_ptr[v]:adg.t2_pred_ptr[v + 1]])

    def _fill(self, robot: int) -> None:
        """Dispatch the robot's next actions while releasable, up to 1 + lookahead held."""
        adg, queue = self.adg, self._queue[robot]
        while len(queue) <= self.lookahead and not self._refusing[robot]:
            v = queue[-1] + 1 if queue else self.monitor.next_vertex(robot)
            if v < 0 or v >= adg.first[robot + 1] or not self._releasable(v):
                return
            self._status[v] = _DISPATCHED
            queue.append(v)
            self._busy += 1
            i = adg.step_of[v]
            self._out.append(Dispatch(self.plan_id, robot, i, adg.src[v], adg.dst[v],
                                      self.monitor.tx[v], adg.heading(robot, i),
                                      adg.heading(robot, i + 1)))
            self._trace("dispatch", robot, adg.step_of[v])

    def _complete(self) -> None:
        self.mode = Mode.DONE
        self._out.append(Completed(self.soc_ms, self.makespan_ms))

    def _trigger(self, policy: str) -> None:
        self.replans += 1
        self.mode = Mode.STOPPING
        slack = self.monitor.fleet_slack()
        self._out.append(Trigger(policy, slack))
        if self._record is not None:
            self._record(trigger_record(self._now, policy, slack))
        adg = self.adg
        for r in range(adg.n_robots):
            for v in self._queue[r]:
                if self._status[v] == _DISPATCHED or self._blocked[v]:
                    self._cancelling[v] = 1
                    self._out.append(Cancel(self.plan_id, r, adg.step_of[v]))
        self._maybe_solve()

    def _maybe_shadow(self, policy: ShadowPolicy) -> None:
        """Ask for a shadow solve if none is outstanding, the last was asked at least the
        policy's period ago, and the fleet is delayed (its slack, or a block lasting, at
        least the policy's minimum)."""
        if self._shadow is not None or self._now < self._next_shadow_ms:
            return
        lasted = max((self._now - since for since in self.blocks.open.values()), default=0.0)
        if max(lasted, self.monitor.fleet_slack()) < policy.min_slack_ms:
            return
        cells, headings, start = self._stop_config()
        self._shadow = (cells, headings)
        self._next_shadow_ms = self._now + policy.period_ms
        self._out.append(SolveRequest(cells, self._goals, headings,
                                      self.blocks.obstacles(start), shadow=True,
                                      start_ms=start))

    def _maybe_solve(self) -> None:
        """In STOPPING, once every robot is idle: adopt the shadow plan the replan was decided
        for if the robots stand where it starts, else request a plan (or finish if nothing
        is left)."""
        if self.mode is not Mode.STOPPING or self._busy:
            return
        ready, self._ready = self._ready, None
        if self._left == 0:
            self._complete()
            return
        if ready is not None and self._fits(ready):
            # (its waits gated by the blocks open now, as a journal's snapshot restores them)
            self._adopt(ready, self._adg_of(ready))
            return
        self.mode = Mode.SOLVING
        self._out.append(SolveRequest(
            tuple(self._cells), self._goals,
            None if self._headings is None else tuple(self._headings),
            self.blocks.obstacles(self._now) if self.informed else ()))
