"""The run contract: what the engine asks of a run (:class:`Run`), and what a run may touch
(:class:`RunContext`).

The engine routes and never asks which mode it is in: a one-shot run
(:class:`~gateway.server.runs.oneshot.OneShotRun`) and a lifelong shift
(:class:`~gateway.server.runs.lifelong.LifelongRun`) answer the same questions (status, the
core robot reports go to, a start pose) and take the same orders (start, pause, replan now,
tick, resume from the journal). Runs see the engine only as a :class:`RunContext`, so nothing
in ``gateway/server/runs`` imports the engine.
"""

from __future__ import annotations

import asyncio
from collections.abc import Callable
from typing import Protocol

from gateway.execution.commands import Command
from gateway.execution.core import Core
from gateway.execution.lifelong.tasks import TaskPool
from gateway.runtime.journal import Journal, ReportRecord, RunRecord
from gateway.server.clock import Clock
from gateway.server.config import GatewayConfig
from gateway.server.items import Item, SolverDone
from gateway.server.metrics import Metrics
from gateway.server.operator_feed import OperatorFeed
from gateway.server.planner import Problem
from gateway.server.runs.resume import JournaledExecutor
from gateway.server.runs.solver_tasks import SolverTasks
from gateway.server.views import ShiftView
from gateway.server.wire.session import Session
from protocol import Pose
from protocol.gateway_session import GatewaySession
from protocol.messages import GatewayStatus, PolicyName


class RunRefused(Exception):
    """The run cannot do what it was asked in its present state (one line, for the operator)."""


class RunContext(Protocol):
    """What a run (and the operator commands driving it) may touch of the engine: the clock,
    the robots' sessions and the routing to them, the journal and its commit, status changes,
    the operator feed, and the run-wide settings operators change."""

    config: GatewayConfig
    clock: Clock
    metrics: Metrics
    queue: asyncio.Queue[Item]
    journal: Journal | None
    feed: OperatorFeed
    solvers: SolverTasks
    robots: dict[int, GatewaySession]
    worlds: set[Session]
    problem: Problem | None
    executor: JournaledExecutor | None
    run_record: RunRecord | None
    run_id: str
    runs: int
    planning: bool
    paused: bool
    replaying: bool
    replayed_trace: list[str]
    summary: tuple[float, float] | None
    finished_event: asyncio.Event
    policy_name: PolicyName
    policy_seed: int
    threshold_ms: float
    block_history: list[float]
    before_start: list[Callable[[], None]]
    before_commit: list[Callable[[], None]]

    @property
    def status(self) -> GatewayStatus:
        """What the gateway is doing."""
        ...

    def now_ms(self) -> float:
        """The present for the run's core (never before its last input)."""
        ...

    def all_online(self, n: int) -> bool:
        """Whether robots 0..n-1 are all connected."""
        ...

    def route(self, commands: list[Command]) -> None:
        """Turn core commands into messages to robots, planner calls and operator events."""

    def flush(self, gs: GatewaySession, sender: Session | None = None) -> None:
        """Carry out a robot session's effects."""

    def replayed_report(self, rec: ReportRecord) -> None:
        """A report the replayed core took: the robot's session takes it too."""

    def commit(self) -> None:
        """Make what was journaled durable, then write the trace records it caused."""

    def status_changed(self) -> None:
        """Tell operators and status listeners what the gateway is doing now."""

    def send_snapshot(self, session: Session) -> None:
        """Send the whole fleet state to one operator."""


class Run(Protocol):
    """What the engine and the operator commands ask of a run, whichever its mode."""

    @property
    def core(self) -> Core[object] | None:
        """What robot reports go to (None: nothing runs yet)."""
        ...

    @property
    def tasks(self) -> TaskPool | None:
        """The live task pool (None: the run has none)."""
        ...

    @property
    def status(self) -> GatewayStatus:
        """What the gateway is doing with this run."""
        ...

    @property
    def ticking(self) -> bool:
        """Whether the engine must tick the run now (started and not done)."""
        ...

    @property
    def planner_busy(self) -> bool:
        """Whether a planner call of the run is under way, or a replan waits for the fleet
        to stop before it (a restart makes that call again, at its own time)."""
        ...

    @property
    def turning(self) -> bool:
        """Whether robots run the ``turning`` motion model (protocol v1 robots cannot)."""
        ...

    @property
    def plan_id(self) -> int | None:
        """The plan a robot's welcome names (None: none)."""
        ...

    @property
    def loads_plans(self) -> bool:
        """Whether an operator may load an instance or a plan into it."""
        ...

    @property
    def active(self) -> bool:
        """Whether a run was started (its speed changes are journaled)."""
        ...

    @property
    def shift_view(self) -> ShiftView | None:
        """What a snapshot shows of a shift (None: not a shift)."""
        ...

    def pose(self, robot: int) -> Pose | None:
        """Where a robot starts (its welcome), None if the run does not know it."""
        ...

    def monitor_tick(self, now_ms: float) -> None:
        """The engine's periodic tick (or a wake-up the core asked for)."""

    def route(self) -> None:
        """Carry out what the core emitted since the last call."""

    def start(self) -> None:
        """Start the run at plan time 0 (:class:`RunRefused` if it cannot start now)."""

    def autostart(self) -> None:
        """Start the run if all its robots are online (the engine checked ``autostart``)."""

    def set_paused(self, paused: bool) -> None:
        """The operator paused or resumed (the engine pauses the robot sessions)."""

    def replan_now(self) -> str:
        """The operator's "replan now"; the answer's detail (:class:`RunRefused`)."""
        ...

    def stop(self) -> str:
        """The operator's "stop the shift"; the answer's detail (:class:`RunRefused`)."""
        ...

    def policy_changed(self, *, replace: bool) -> None:
        """The operator set the policy (``replace``) or the threshold."""

    def solver_done(self, item: SolverDone) -> None:
        """A solver task the run asked for answered."""

    def resume(self) -> bool:
        """Rebuild the run from the engine's journal and carry on; True if a journaled run
        goes on."""
        ...

    def cancel(self) -> None:
        """The gateway is closing: stop what the run runs off the loop."""
