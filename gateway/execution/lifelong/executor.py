"""Lifelong execution for a driver (sans-I/O): a warehouse shift on a live ADG.

:class:`LifelongExecutor` wraps :class:`~gateway.execution.lifelong.live_adg.LiveADG`. Every
``period_ms`` (at a :meth:`~LifelongExecutor.tick`; at a fixed rate: a call made late does not
push the later ones back, :meth:`~LifelongExecutor.next_wakeup_ms` says when the next is due)
it assigns tasks to robots without one
(:class:`~gateway.execution.lifelong.errands.ErrandBook` over a
:class:`~gateway.execution.lifelong.tasks.TaskPool`)
and asks its driver for the next window of the plan with a :class:`PlanRequest` (the driver runs
the planner off its event loop and answers :meth:`~LifelongExecutor.adopt` with a
:class:`Segment`). An adopted segment is appended to the live ADG while the robots move:
nothing dispatched changes and no robot stops for it. Robots get :class:`Dispatch` commands
(the one-shot executor's, so the wire protocol is the same: ``plan`` is the segment that
committed the action, ``action`` the robot's action number over the whole run, so action ids
never repeat), up to ``lookahead`` actions beyond the one they run, each only once its Type 2
dependency is done (the Type 1 order is the robot's: it runs its queue in order). Reports
(started, finished, blocked, unblocked, stopped, refused) are checked against the head of the
robot's queue like the one-shot executor's. A robot completes an errand when it finishes the
action that brings it onto the errand's cell; the task pool is told. A robot may refuse an
action it has not started: it and the robot's later dispatched actions are taken back and
dispatched again, unchanged, at the next planning call.

Monitor: :meth:`~LifelongExecutor.estimate` is Algorithm 1 over every committed action of every
segment (``LiveADG.estimate``). Slack across segments: each action has one Type 2 dependency in
the live ADG (the last robot that left its cell before it, which orders it after every earlier
visit), so Δ(a) = max(0, t_c(dep) - t_c(the robot's previous action)) while the dependency is
not done (0 once it is: the robot no longer waits for it); Δ0(a) is Δ(a) on the estimate when
its segment was adopted, and Δ̄F the largest Δ - Δ0 over actions not started. When Δ̄F exceeds
``threshold_ms`` (checked every ``monitor_period_ms``) the executor does what lifelong mode can
do without stopping anyone: it records a ``trigger`` and calls the planner at once instead of
at the end of the period (the new window plans the other robots around late ones), and Δ0 of
every pending action starts again from the present estimate, as a replan's new plan would.

The state is a deterministic function of the inputs (start, ticks, adopted segments, reports,
with their times), so a journal can replay it. Trace records: a ``plan`` record with
``"lifelong": true`` whose paths are the start poses, a ``segment`` record per adopted segment
(every robot's states step by step, waits included), and event records whose ``action`` is the
robot's action number over the run (waits are no actions).
"""

from __future__ import annotations

import enum
import math
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

from gateway.execution.actions import ActionDurations
from gateway.execution.commands import Completed, Dispatch, Trigger
from gateway.execution.core import check_robot, check_start, check_time
from gateway.execution.errors import ExecutionError
from gateway.execution.lifelong.errands import ErrandBook, TaskDistances
from gateway.execution.lifelong.live_adg import LiveAction, LiveADG
from gateway.execution.lifelong.tasks import SCHEDULERS, Scheduler, TaskPool
from gateway.execution.trace_records import (
    Record,
    TraceSink,
    event_record,
    plan_record,
    trigger_record,
)
from gateway.planning.grid import Grid
from gateway.planning.pibt import StateSpace, WindowedPIBT


@dataclass(frozen=True, slots=True)
class PlanRequest:
    """Plan window ``call`` for ``steps`` timesteps from ``starts`` (planner states: a cell
    id, or ``cell * 4 + heading`` under ``turning``) to each robot's remaining errand cells
    ``goals[r]``; robot r waits through the first ``hold[r]`` steps (its committed actions but
    one), and nobody enters a cell of ``avoid`` (cells late robots still have to drive
    through). The driver answers :meth:`LifelongExecutor.adopt` (or
    :meth:`LifelongExecutor.plan_failed`)."""

    call: int
    starts: tuple[int, ...]
    goals: tuple[tuple[int, ...], ...]
    hold: tuple[int, ...]
    avoid: tuple[int, ...]
    steps: int
    priorities: tuple[int, ...] = ()
    """PIBT's priorities the call starts from (per robot, timesteps since it last reached a
    goal: the previous adopted segment's) with a random stream of the call's own; empty: the
    planner goes on from its earlier calls (the LoRR simulator's requests)."""


@dataclass(frozen=True, slots=True)
class Segment:
    """The planner's window for request ``call``: ``states[j][r]`` is robot r's planner state
    at step j (step 0 = the request's ``starts``); ``reached[r]`` the steps at which it stands
    on each of its goals, in order; ``priorities`` PIBT's priorities at the window's end (the
    next call's start; empty: not known, e.g. a journal written before they were kept)."""

    call: int
    states: Sequence[Sequence[int]]
    reached: Sequence[Sequence[int]]
    priorities: Sequence[int] = ()


def window_request(call: int, book: ErrandBook, adg: LiveADG, scheduler: Scheduler,
                   distances: TaskDistances, now: float, *, release: bool,
                   late: Sequence[bool], hold: Sequence[int], steps: int, turning: bool,
                   release_robots: Sequence[int] | None = None,
                   priorities: Sequence[int] = ()
                   ) -> tuple[PlanRequest, list[tuple[int, int]]]:
    """Planning call ``call`` at ``now``: give the robots without a task one (their unstarted
    tasks back to the scheduler first if ``release``, only those of ``release_robots`` if
    given; a ``late`` robot competes with the
    distance charge of ``distances``) and ask for ``steps`` timesteps from where each robot's
    committed plan ends, robot r holding through ``hold[r]`` steps and nobody entering a cell a
    late robot still has to drive through. The request and the new ``(robot, task id)``
    pairs; the call starts from PIBT's ``priorities`` (empty: the planner's own). The
    executor's and the LoRR simulator's call (``sim_clients.lifelong``)."""
    n = len(adg.end_cell)
    if release:
        book.release_unstarted(now, release_robots)
    distances.charged = {adg.end_cell[r] for r in range(n) if late[r]}
    assigned = book.schedule(adg.end_cell, scheduler, distances, now)
    goals = tuple(book.goals())
    if turning:
        starts = tuple(4 * c + h for c, h in zip(adg.end_cell, adg.end_heading, strict=True))
    else:
        starts = tuple(adg.end_cell)
    avoid = tuple(a.cell for r in range(n) if late[r] for a in adg.queue[r])
    return PlanRequest(call, starts, goals, tuple(hold), avoid, steps,
                       tuple(priorities)), assigned


LifelongCommand = Dispatch | Trigger | Completed | PlanRequest
"""What :meth:`LifelongExecutor.drain` hands the driver."""


class LifelongMode(enum.Enum):
    """Where a lifelong run is."""

    NEW = "new"
    RUNNING = "running"
    STOPPING = "stopping"  # nothing new is dispatched; the run ends when the robots are idle
    DONE = "done"


_NO_START = -1.0


class LifelongExecutor:
    """Executes a warehouse shift: tasks, periodic windows appended to a live ADG, dispatch.

    ``starts`` are flat cell ids (``grid.index``), ``headings`` the start headings under the
    ``turning`` model (None: ``omni``). ``window`` timesteps are planned per call (0: enough
    for a period, ``ceil(period_ms / move_ms)``). ``threshold_ms`` None turns the slack
    trigger off.
    """

    def __init__(self, grid: Grid, starts: Sequence[int], headings: Sequence[int] | None,
                 pool: TaskPool, *, scheduler: str = "shortest",
                 distances: TaskDistances | None = None, period_ms: float = 1000.0,
                 window: int = 0, durations: ActionDurations | None = None,
                 lookahead: int = 1, threshold_ms: float | None = None,
                 monitor_period_ms: float = 500.0, reassign: int = 1,
                 record: TraceSink | None = None) -> None:
        if scheduler not in SCHEDULERS:
            raise ExecutionError(f"unknown scheduler {scheduler!r}; expected one of "
                                 f"{sorted(SCHEDULERS)}")
        if not (math.isfinite(period_ms) and period_ms > 0):
            raise ExecutionError(f"period_ms must be a positive number, got {period_ms}")
        if lookahead < 0 or window < 0 or reassign < 0:
            raise ExecutionError("lookahead, window and reassign must be >= 0")
        self.grid = grid
        self.n = len(starts)
        self.adg = LiveADG(grid, starts, headings)
        self.turning = headings is not None
        self.pool = pool
        self.book = ErrandBook(pool, self.n)
        self.scheduler = SCHEDULERS[scheduler]
        self.distances = distances if distances is not None else TaskDistances(grid)
        self.period_ms = period_ms
        d = durations if durations is not None else ActionDurations()
        self.durations = d
        self._tx = (d.move_ms, d.turn_ms, d.turn_ms)  # by LiveAction kind
        self.window = window or max(1, math.ceil(period_ms / d.move_ms))
        self.lookahead = lookahead
        self.threshold_ms = threshold_ms
        self.monitor_period_ms = monitor_period_ms
        self.reassign = reassign
        self._record = record
        self.mode = LifelongMode.NEW
        self.paused = False
        self._now = 0.0
        self._out: list[LifelongCommand] = []
        n = self.n
        self.cell = list(starts)
        """Where each robot stands (the target of a running move once it finishes)."""
        self.heading = list(headings) if headings is not None else [0] * n
        self._sent = [0] * n  # dispatched, unfinished actions (the head first)
        self._started_at = [_NO_START] * n  # start time of the running head action
        self._blocked = bytearray(n)
        self._refusing = bytearray(n)  # refused an action: nothing until the next call
        self._waiters: list[set[int]] = [set() for _ in range(n)]  # robots whose next dispatch
        # waits for an action of this robot
        self._segment_of: list[deque[tuple[int, int]]] = [deque() for _ in range(n)]
        # per robot: (first action number, segment) of each segment with actions for it
        self._slack0: list[deque[float]] = [deque() for _ in range(n)]  # Δ0 of pending actions
        self.completion = [0.0] * n
        """Finish time of each robot's latest action."""
        self.calls = 0
        """Planner calls requested."""
        self.segments = 0
        """Segments adopted (the next segment's number)."""
        self.outstanding: PlanRequest | None = None
        """The planner call not answered yet."""
        self.priorities = [0] * n
        """PIBT's priorities after the latest adopted segment (the next call starts from
        them: the planner keeps none of its own, so a restarted one plans the same)."""
        self._next_call = 0.0
        self._next_check = 0.0
        self.fleet_slack_ms = 0.0
        """Δ̄F at the last slack check."""
        self._slack_based = True  # Δ0 is known for every pending action
        self.triggers = 0
        self.errands_done = 0

    # ------------------------------------------------------------------ queries
    @property
    def now_ms(self) -> float:
        """Time of the latest accepted input."""
        return self._now

    @property
    def done(self) -> bool:
        """True once a stopped run has no robot busy."""
        return self.mode is LifelongMode.DONE

    @property
    def finished_tasks(self) -> int:
        """Tasks finished so far."""
        return self.pool.finished

    def pose(self, robot: int) -> tuple[int, int | None]:
        """``(cell id, heading)`` of a robot (heading None under ``omni``)."""
        return self.cell[robot], (self.heading[robot] if self.turning else None)

    def busy(self, robot: int) -> int:
        """The robot's dispatched, unfinished actions."""
        return self._sent[robot]

    def dispatched(self, robot: int) -> list[Dispatch]:
        """The robot's dispatched, unfinished actions, as they were dispatched (a shift
        restored from a snapshot tells the robot sessions with them)."""
        q = self.adg.queue[robot]
        return [self._command(robot, pos, q[pos], q[pos - 1] if pos else None)
                for pos in range(self._sent[robot])]

    def head_state(self, robot: int) -> tuple[bool, bool]:
        """Whether the robot's first dispatched action is started, and whether it is
        blocked."""
        return self._started_at[robot] != _NO_START, bool(self._blocked[robot])

    def drain(self) -> list[LifelongCommand]:
        """The commands emitted since the last call, in order."""
        out, self._out = self._out, []
        return out

    def next_wakeup_ms(self) -> float | None:
        """When the executor wants its next :meth:`tick` (None: no need)."""
        if self.mode is not LifelongMode.RUNNING:
            return None
        return self._next_call if self.outstanding is None else None

    def estimate(self, now_ms: float) -> list[list[float]]:
        """Algorithm 1 across segments: per robot, the estimated completion of each committed,
        unfinished action (in order), with the running ones' progress counted."""
        progress = [0.0] * self.n
        for r, t0 in enumerate(self._started_at):
            if t0 != _NO_START:
                head = self.adg.head(r)
                assert head is not None
                # a running action ends no earlier than now
                progress[r] = min(now_ms - t0, self._tx[head.kind])
        return self.adg.estimate(now_ms, progress, self._tx)

    # ------------------------------------------------------------------ snapshot
    def snapshot(self) -> dict[str, Any]:
        """The executor's own state as plain data (a shift snapshot's executor fields; its
        live ADG, errand book, task pool and outstanding call are snapshotted apart).
        Commands not drained yet are output, not state: a driver snapshots after routing
        them."""
        return {
            "mode": self.mode.value, "paused": self.paused, "now_ms": self._now,
            "threshold_ms": self.threshold_ms, "cell": list(self.cell),
            "heading": list(self.heading), "sent": list(self._sent),
            "started_at": list(self._started_at), "blocked": list(self._blocked),
            "refusing": list(self._refusing), "waiters": [sorted(w) for w in self._waiters],
            "segment_of": [list(s) for s in self._segment_of],
            "completion": list(self.completion), "slack0": [list(s) for s in self._slack0],
            "slack_based": self._slack_based, "fleet_slack_ms": self.fleet_slack_ms,
            "next_call_ms": self._next_call, "next_check_ms": self._next_check,
            "calls": self.calls, "segments": self.segments, "triggers": self.triggers,
            "errands_done": self.errands_done, "priorities": list(self.priorities)}

    def restore(self, *, mode: str, paused: bool, now_ms: float, threshold_ms: float | None,
                cell: Sequence[int], heading: Sequence[int], sent: Sequence[int],
                started_at: Sequence[float], blocked: Sequence[int], refusing: Sequence[int],
                waiters: Sequence[Sequence[int]], segment_of: Sequence[Sequence[Sequence[int]]],
                completion: Sequence[float], slack0: Sequence[Sequence[float]],
                slack_based: bool, fleet_slack_ms: float, next_call_ms: float,
                next_check_ms: float, calls: int, segments: int, triggers: int,
                errands_done: int, priorities: Sequence[int],
                outstanding: PlanRequest | None) -> None:
        """Take the state :meth:`snapshot` gave (and the outstanding planner call), in a
        fresh executor of the same configuration (ExecutionError if it was started); empty
        ``priorities`` (a snapshot written before they were kept) start afresh."""
        if self.mode is not LifelongMode.NEW:
            raise ExecutionError("a snapshot is restored into a shift not started yet")
        self.mode = LifelongMode(mode)
        self.paused, self._now, self.threshold_ms = paused, now_ms, threshold_ms
        self.cell, self.heading = list(cell), list(heading)
        self._sent, self._started_at = list(sent), list(started_at)
        self._blocked, self._refusing = bytearray(blocked), bytearray(refusing)
        self._waiters = [set(w) for w in waiters]
        self._segment_of = [deque((f, s) for f, s in seg) for seg in segment_of]
        self.completion = list(completion)
        self._slack0 = [deque(s) for s in slack0]
        self._slack_based, self.fleet_slack_ms = slack_based, fleet_slack_ms
        self._next_call, self._next_check = next_call_ms, next_check_ms
        self.calls, self.segments = calls, segments
        self.outstanding = outstanding
        self.triggers, self.errands_done = triggers, errands_done
        self.priorities = list(priorities) if priorities else [0] * self.n

    # ------------------------------------------------------------------ lifecycle
    def start(self, now_ms: float) -> None:
        """Begin the shift: the first planning call is due now."""
        check_start(now_ms, self.mode is not LifelongMode.NEW)
        self.mode = LifelongMode.RUNNING
        self._now = self._next_call = self._next_check = now_ms
        if self._record is not None:
            paths = [[self.grid.cell(c)] for c in self.cell]
            rec = plan_record(now_ms, 0, paths,
                              [[h] for h in self.heading] if self.turning else None)
            rec["lifelong"] = True
            self._record(rec)
        self._call()

    def stop(self, now_ms: float) -> None:
        """End the shift: nothing new is dispatched or planned; the run is done (a
        :class:`Completed`) once every robot finished what it was dispatched."""
        self._check_time(now_ms)
        if self.mode is not LifelongMode.RUNNING:
            raise ExecutionError(f"cannot stop: the run is {self.mode.value}")
        self._now = now_ms
        self.mode = LifelongMode.STOPPING
        self._maybe_done()

    def pause(self, now_ms: float) -> None:
        """Dispatch nothing new until :meth:`resume` (running and queued actions go on)."""
        self._check_time(now_ms)
        self._now = now_ms
        self.paused = True

    def resume(self, now_ms: float) -> None:
        """Dispatch again."""
        self._check_time(now_ms)
        self._now = now_ms
        self.paused = False
        for r in range(self.n):
            self._fill(r)

    def tick(self, now_ms: float) -> None:
        """The present moved on: plan when the period is over, check the fleet slack."""
        self._check_time(now_ms)
        self._now = now_ms
        if self.mode is not LifelongMode.RUNNING:
            return
        if self.threshold_ms is not None and now_ms >= self._next_check:
            self._next_check = now_ms + self.monitor_period_ms
            slacks = self._slacks(self.estimate(now_ms))
            if not self._slack_based:  # the threshold was off: Δ0 starts from now
                self._slack0 = [deque(row) for row in slacks]
                self._slack_based = True
            self.fleet_slack_ms = self._fleet_slack(slacks)
            if self.fleet_slack_ms > self.threshold_ms and self.outstanding is None \
                    and now_ms < self._next_call:
                # the growth so far is answered: Δ0 starts again from the present estimate
                self._slack0 = [deque(row) for row in slacks]
                self.triggers += 1
                self._out.append(Trigger("slack", self.fleet_slack_ms))
                if self._record is not None:
                    self._record(trigger_record(now_ms, "slack", self.fleet_slack_ms))
                self._next_call = now_ms
        if self.outstanding is None and now_ms >= self._next_call and not self.paused:
            self._call()

    def plan_now(self, now_ms: float) -> None:
        """The operator's "replan now": the next planning call is made at once (a
        ``trigger`` record says so); nothing committed changes."""
        self._check_time(now_ms)
        if self.mode is not LifelongMode.RUNNING or self.outstanding is not None:
            raise ExecutionError("cannot plan now: "
                                 + ("a planner call is running" if self.outstanding
                                    is not None else f"the run is {self.mode.value}"))
        self._now = now_ms
        self._out.append(Trigger("operator", self.fleet_slack_ms))
        if self._record is not None:
            self._record(trigger_record(now_ms, "operator", self.fleet_slack_ms))
        self._call()

    # ------------------------------------------------------------------ planning
    def late(self, now_ms: float) -> list[bool]:
        """Robots behind their plan: blocked, or running an action longer than expected."""
        tx = self._tx
        out = []
        for r in range(self.n):
            t0 = self._started_at[r]
            head = self.adg.head(r)
            out.append(bool(self._blocked[r]) or (
                t0 != _NO_START and head is not None and now_ms - t0 > tx[head.kind]))
        return out

    def _call(self) -> None:
        """Assign tasks and ask the driver for the next window; the robots that refused an
        action get it again."""
        adg, book, n = self.adg, self.book, self.n
        if any(self._refusing):
            refusing = [r for r in range(n) if self._refusing[r]]
            self._refusing = bytearray(n)
            for r in refusing:
                self._fill(r)
        book.forget_gone()  # first: a task cancelled or paused is no robot's to release
        self.outstanding, _ = window_request(
            self.calls, book, adg, self.scheduler, self.distances, self._now,
            release=bool(self.reassign) and self.calls % self.reassign == 0,
            late=self.late(self._now), hold=[max(0, adg.pending(r) - 1) for r in range(n)],
            steps=self.window, turning=self.turning, priorities=self.priorities)
        self._out.append(self.outstanding)
        self.calls += 1
        # fixed rate: the next call is due a period after this one was due, so a call made
        # late (a busy driver, a slow answer) does not push every later one back; one made
        # early (a trigger, the operator) starts the period again
        due = min(self._next_call, self._now)
        self._next_call = max(due + self.period_ms, self._now)

    def plan_failed(self, call: int, now_ms: float) -> None:
        """The planner could not answer call ``call``: the next period plans again."""
        self._check_time(now_ms)
        self._check_call(call)
        self._now = now_ms
        self.outstanding = None

    def _check_call(self, call: int) -> None:
        if self.outstanding is None or self.outstanding.call != call:
            raise ExecutionError(f"no planner call {call} is outstanding")

    def adopt(self, segment: Segment, now_ms: float) -> None:
        """Append the planner's window to the live ADG (ExecutionError, changing nothing, if it
        does not start from the committed end states or is not 1-robust) and dispatch what it
        makes ready."""
        self._check_time(now_ms)
        self._check_call(segment.call)
        if len(segment.reached) != self.n:
            raise ExecutionError(f"a segment needs reached steps for {self.n} robots")
        if len(segment.priorities) not in (0, self.n):
            raise ExecutionError(f"a segment needs priorities for {self.n} robots (or none)")
        adg = self.adg
        if self.turning:
            cells = [[s >> 2 for s in row] for row in segment.states]
            heads: list[list[int]] | None = [[s & 3 for s in row] for row in segment.states]
        else:
            cells = [list(row) for row in segment.states]
            heads = None
        before = list(adg.appended)
        adg.append(cells, heads)  # checks the segment; raises before anything changes
        self._now = now_ms
        self.outstanding = None
        number = self.segments
        self.segments += 1
        if segment.priorities:
            self.priorities = list(segment.priorities)
        tasks_of = self.book.planned(segment.reached)
        self.book.register(before, segment.states, segment.reached, tasks_of)
        for r in range(self.n):
            if adg.appended[r] > before[r]:
                self._segment_of[r].append((before[r], number))
        if self._record is not None:
            self._record(self._segment_record(number, cells, heads))
        self._initial_slack(before)
        for r in range(self.n):
            self._errands(r)
            self._fill(r)
        self._maybe_done()

    def _segment_record(self, number: int, cells: list[list[int]],
                        heads: list[list[int]] | None) -> Record:
        cell_of = self.grid.cell
        agents = []
        for r in range(self.n):
            if heads is None:
                path = [list(cell_of(row[r])) for row in cells]
            else:
                path = [[*cell_of(row[r]), hrow[r]] for row, hrow in zip(cells, heads,
                                                                        strict=True)]
            agents.append({"path": path})
        return {"t_ms": self._now, "type": "segment", "plan": 0, "segment": number,
                "agents": agents}

    # ------------------------------------------------------------------ slack
    def _slacks(self, est: list[list[float]]) -> list[list[float]]:
        """Δ of every pending action on the estimate ``est`` (see the module doc)."""
        adg = self.adg
        out: list[list[float]] = []
        for r in range(self.n):
            row = []
            prev = self.completion[r]
            for i, a in enumerate(adg.queue[r]):
                delta = 0.0
                d = a.dep_robot
                if d >= 0 and adg.done[d] <= a.dep_seq:
                    delta = max(0.0, est[d][a.dep_seq - adg.done[d]] - prev)
                row.append(delta)
                prev = est[r][i]
            out.append(row)
        return out

    def _initial_slack(self, before: Sequence[int]) -> None:
        """Δ0 of the actions just appended (robot r's from number ``before[r]`` on)."""
        if self.threshold_ms is None:
            self._slack_based = False
            return
        slacks = self._slacks(self.estimate(self._now))
        adg = self.adg
        for r in range(self.n):
            first = before[r] - adg.done[r]
            self._slack0[r].extend(slacks[r][first:])

    def _fleet_slack(self, slacks: list[list[float]]) -> float:
        """Δ̄F: the largest Δ - Δ0 over the actions not started."""
        best = 0.0
        for r in range(self.n):
            skip = 1 if self._started_at[r] != _NO_START else 0
            for i, (s, s0) in enumerate(zip(slacks[r], self._slack0[r], strict=True)):
                if i >= skip and s - s0 > best:
                    best = s - s0
        return best

    # ------------------------------------------------------------------ robot events
    def _check_time(self, now_ms: float) -> None:
        check_time(now_ms, self._now, self.mode is not LifelongMode.NEW, "the lifelong run")

    def _event(self, kind: str, robot: int, plan: int, action: int, now_ms: float) -> int:
        """Check a report about ``action`` of ``robot`` (segment ``plan``); return its
        position in the robot's dispatched actions."""
        self._check_time(now_ms)
        check_robot(robot, self.n)
        pos = action - self.adg.done[robot]
        if pos < 0:
            raise ExecutionError(f"{kind} of robot {robot} action {action}: that action is "
                                 "finished")
        if pos >= self._sent[robot]:
            raise ExecutionError(f"{kind} of robot {robot} action {action}: that action is "
                                 "not dispatched")
        if self.segment_of(robot, action) != plan:
            raise ExecutionError(f"{kind} of robot {robot} action {action} names segment "
                                 f"{plan}, but it belongs to segment "
                                 f"{self.segment_of(robot, action)}")
        if kind != "refused" and pos != 0:
            raise ExecutionError(f"{kind} of robot {robot} action {action}: it is queued "
                                 f"behind action {self.adg.done[robot]}, which has not finished")
        return pos

    def segment_of(self, robot: int, action: int) -> int:
        """The segment that committed the robot's action number ``action`` (pending ones)."""
        seg = -1
        for first, number in self._segment_of[robot]:
            if first > action:
                break
            seg = number
        return seg

    def started(self, robot: int, plan: int, action: int, now_ms: float) -> None:
        """The robot began the action (after any wait for its cell)."""
        self._event("start", robot, plan, action, now_ms)
        if self._started_at[robot] != _NO_START:
            raise ExecutionError(f"start of robot {robot} action {action}: already started")
        self._now = now_ms
        self._started_at[robot] = now_ms
        self._blocked[robot] = 0
        self._trace("start", robot, action)

    def finished(self, robot: int, plan: int, action: int, now_ms: float) -> None:
        """The robot completed the action."""
        self._event("finish", robot, plan, action, now_ms)
        if self._started_at[robot] == _NO_START:
            raise ExecutionError(f"finish of robot {robot} action {action}: it has not "
                                 "started (no start reported)")
        self._now = now_ms
        a = self.adg.finish(robot)
        self._sent[robot] -= 1
        self._started_at[robot] = _NO_START
        self._blocked[robot] = 0
        if self._slack0[robot]:
            self._slack0[robot].popleft()
        segs = self._segment_of[robot]
        while len(segs) > 1 and segs[1][0] <= self.adg.done[robot]:
            segs.popleft()
        self.cell[robot], self.heading[robot] = a.cell, a.heading
        self.completion[robot] = now_ms
        self._trace("finish", robot, action)
        self._errands(robot)
        self._fill(robot)
        waiters = self._waiters[robot]
        if waiters:
            self._waiters[robot] = set()
            for r in sorted(waiters):
                self._fill(r)
        self._maybe_done()

    def blocked(self, robot: int, plan: int, action: int, now_ms: float) -> None:
        """The robot found the action's target cell taken and waits."""
        self._event("blocked", robot, plan, action, now_ms)
        if self._started_at[robot] != _NO_START or self._blocked[robot]:
            raise ExecutionError(f"blocked of robot {robot} action {action}: it is already "
                                 "started or blocked")
        self._now = now_ms
        self._blocked[robot] = 1
        self._trace("blocked", robot, action)

    def stopped(self, robot: int, plan: int, action: int, now_ms: float) -> None:
        """A move under way was stopped by an obstacle (protocol v2 ``blocked`` after
        ``started``); ``unblocked`` when it drives on. Lifelong mode cancels nothing, so the
        robot completes it when the obstacle is gone."""
        self._event("blocked", robot, plan, action, now_ms)
        if self._started_at[robot] == _NO_START or self._blocked[robot]:
            raise ExecutionError(f"blocked of robot {robot} action {action}: only a move "
                                 "under way can be stopped on the way")
        self._now = now_ms
        self._blocked[robot] = 1
        self._trace("blocked", robot, action)

    def unblocked(self, robot: int, plan: int, action: int, now_ms: float) -> None:
        """The action's target cell became free again."""
        self._event("unblocked", robot, plan, action, now_ms)
        if not self._blocked[robot]:
            raise ExecutionError(f"unblocked of robot {robot} action {action}: it is not "
                                 "blocked")
        self._now = now_ms
        self._blocked[robot] = 0
        self._trace("unblocked", robot, action)

    def cancelled(self, robot: int, plan: int, action: int, now_ms: float) -> None:
        """Lifelong mode cancels nothing: any ``cancelled`` is refused."""
        self._event("cancelled", robot, plan, action, now_ms)
        raise ExecutionError(f"cancelled of robot {robot} action {action}: no cancel is "
                             "outstanding for it")

    def refused(self, robot: int, plan: int, action: int, now_ms: float,
                reason: str = "") -> None:
        """The robot will not execute the action (not started): it and the robot's later
        dispatched ones go back to committed, not dispatched (a ``refused`` trace record each,
        the first with the reason). Its committed actions cannot be withdrawn (robots that
        depend on them wait), so the robot gets them again, the refused one first, at the next
        planning call (as a one-shot replan gives a refusing robot work again): at most one
        refusal per period if the robot keeps refusing."""
        pos = self._event("refused", robot, plan, action, now_ms)
        if pos == 0 and self._started_at[robot] != _NO_START:
            raise ExecutionError(f"refused of robot {robot} action {action}: it has already "
                                 "started")
        self._now = now_ms
        first = self.adg.done[robot] + pos
        for number in range(first, self.adg.done[robot] + self._sent[robot]):
            self._trace("refused", robot, number, reason if number == first else None)
        self._sent[robot] = pos
        if pos == 0:
            self._blocked[robot] = 0
        self._refusing[robot] = 1
        self._maybe_done()

    # ------------------------------------------------------------------ internals
    def _errands(self, robot: int) -> None:
        """Tell the pool about the errands the robot's finished actions completed."""
        for task_id in self.book.reach(robot, self.adg.done[robot]):
            task = self.pool.tasks.get(task_id)
            if task is not None and task.robot == robot:  # not cancelled or paused meanwhile
                self.pool.errand_done(task_id, self._now, robot)
                self.errands_done += 1

    def _fill(self, robot: int) -> None:
        """Dispatch the robot's next actions while their dependencies are done, up to
        ``1 + lookahead`` held."""
        if self.mode is not LifelongMode.RUNNING or self.paused or self._refusing[robot]:
            return
        adg = self.adg
        queue = adg.queue[robot]
        while self._sent[robot] <= self.lookahead and self._sent[robot] < len(queue):
            pos = self._sent[robot]
            a = queue[pos]
            if a.dep_robot >= 0 and adg.done[a.dep_robot] <= a.dep_seq:
                self._waiters[a.dep_robot].add(robot)
                return
            self._sent[robot] += 1
            self._dispatch(robot, pos, a, queue[pos - 1] if pos else None)

    def _dispatch(self, robot: int, pos: int, a: LiveAction, prev: LiveAction | None) -> None:
        self._out.append(self._command(robot, pos, a, prev))
        self._trace("dispatch", robot, self.adg.done[robot] + pos)

    def _command(self, robot: int, pos: int, a: LiveAction, prev: LiveAction | None
                 ) -> Dispatch:
        """The dispatch of the robot's pending action ``a`` at ``pos`` (after ``prev``)."""
        number = self.adg.done[robot] + pos
        src_cell, src_heading = (self.cell[robot], self.heading[robot]) if prev is None \
            else (prev.cell, prev.heading)
        cell_of = self.grid.cell
        return Dispatch(
            self.segment_of(robot, number), robot, number, cell_of(src_cell), cell_of(a.cell),
            self._tx[a.kind], src_heading if self.turning else None,
            a.heading if self.turning else None)

    def _maybe_done(self) -> None:
        if self.mode is LifelongMode.STOPPING and not any(self._sent):
            self.mode = LifelongMode.DONE
            soc = sum(self.completion)
            self._out.append(Completed(soc, max(self.completion, default=0.0)))

    def _trace(self, kind: str, robot: int, action: int, reason: str | None = None) -> None:
        if self._record is not None:
            self._record(event_record(self._now, kind, 0, robot, action, reason))


class WindowPlanner:
    """Answers :class:`PlanRequest` with :class:`~gateway.planning.pibt.WindowedPIBT` (a
    driver may run it in a worker thread, one call at a time). A request with priorities (the
    executor's) is planned from them and a random stream of its own (the call's number), so
    a restarted planner answers it as the first did; one without (the LoRR simulator's) goes
    on from the priorities and the random stream the previous call left. ``guided``: tables
    guided by the crowd (:attr:`~gateway.planning.pibt.WindowedPIBT.guided`): the LoRR
    simulator's, not the executor's, as a restarted planner would not answer as the first.
    ``turn_to_leaving``: :attr:`~gateway.planning.pibt.WindowedPIBT.turn_to_leaving`."""

    def __init__(self, grid: Grid, n_robots: int, turning: bool, seed: int = 0,
                 space: StateSpace | None = None, guided: bool = False,
                 turn_to_leaving: bool = False, lns: int = 0) -> None:
        self.space = space if space is not None else StateSpace(grid, turning, robots=n_robots)
        self.pibt = WindowedPIBT(self.space, n_robots, seed=seed, guided=guided,
                                 turn_to_leaving=turn_to_leaving, lns=lns)

    def __call__(self, req: PlanRequest) -> Segment:
        """The window for ``req``."""
        pibt = self.pibt
        if req.priorities:
            pibt.start_from(req.priorities, req.call)
        win = pibt.plan(req.starts, req.goals, req.steps, req.hold, req.avoid)
        return Segment(req.call, win.states, win.reached, tuple(pibt.elapsed))
