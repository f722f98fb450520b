"""Operator commands, and the run lifecycle they drive: load, start, pause, replan, settings.

The engine hands every operator command (from an operator's connection, or from inside the
process with a future to answer) to :meth:`OperatorCommands.handle`; it checks the command
against the gateway's status, changes the run, and answers ``ok`` or ``error`` with a code.
A load that needs the planner is answered when the plan comes back
(:meth:`OperatorCommands.load_solved`). What the executor says in return goes back through
the engine's routing.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import replace
from typing import Protocol, TypeVar

from gateway.planning.plan import Plan
from gateway.runtime.journal import SpeedRecord
from gateway.server.items import Reply, SolverDone
from gateway.server.planner import (
    InstanceError,
    Problem,
    problem_from_paths,
    resolve_instance,
    without_paths,
)
from gateway.server.runs.base import Run, RunContext, RunRefused
from gateway.server.wire.session import Session
from protocol import (
    ErrorCode,
    GetSnapshot,
    LoadInstance,
    LoadPlan,
    Ok,
    OperatorCommand,
    Pause,
    PlaceIntruder,
    ReplanNow,
    Resume,
    SetPolicy,
    SetSpeed,
    SetThreshold,
    Start,
    StopShift,
)

T = TypeVar("T")


class CommandContext(RunContext, Protocol):
    """What operator commands drive: the engine's run and what a run may touch."""

    current_run: Run


class CommandError(Exception):
    """An operator command is refused with ``code``."""

    def __init__(self, code: ErrorCode, detail: str) -> None:
        super().__init__(detail)
        self.code = code
        self.detail = detail


def reply_to(reply: Reply, ref: str | None, code: ErrorCode | None, detail: str) -> None:
    """Answer a command: ``ok``/``error`` to an operator's session, or set an in-process
    caller's future to ``(code, detail)`` (``code`` None = done)."""
    if isinstance(reply, Session):
        if code is None:
            reply.send(Ok, ref=ref or "", detail=detail)
        else:
            reply.error(code, ref, without_paths(detail))
    elif reply is not None and not reply.done():
        reply.set_result((code, detail))


class OperatorCommands:
    """Carries out operator commands on the engine's run (the engine's owner task calls it)."""

    def __init__(self, engine: CommandContext) -> None:
        self._engine = engine

    def handle(self, msg: OperatorCommand, reply: Reply) -> None:
        """Carry out ``msg`` and answer on ``reply`` (now, or when the planner is done)."""
        try:
            detail = self._execute(msg, reply)
        except CommandError as exc:
            reply_to(reply, msg.msg_id, exc.code, exc.detail)
            return
        if detail is not None:
            reply_to(reply, msg.msg_id, None, detail)

    def _idle(self, what: str) -> None:
        e = self._engine
        if not e.current_run.loads_plans:
            raise CommandError(ErrorCode.BAD_STATE, f"cannot {what} in lifelong mode")
        if e.planning or e.status in ("running", "paused", "replanning"):
            raise CommandError(ErrorCode.BAD_STATE, f"cannot {what} while {e.status}")

    def _execute(self, msg: OperatorCommand, reply: Reply) -> str | None:
        """Carry out a command; returns the Ok detail, or None if the reply comes later."""
        e = self._engine
        match msg:
            case LoadInstance():
                self._idle("load an instance")
                if msg.scen is not None and msg.generate is not None:
                    raise CommandError(ErrorCode.BAD_REQUEST, "give scen or generate, not both")
                seed = msg.generate.seed if msg.generate else e.config.generate_seed
                try:
                    problem = resolve_instance(msg.map, msg.scen, msg.agents, seed)
                except InstanceError as exc:
                    raise CommandError(ErrorCode.BAD_REQUEST, exc.public) from None
                self.load(problem, reply, msg.msg_id)
                return None
            case LoadPlan():
                self._idle("load a plan")
                try:
                    problem = problem_from_paths(msg.map, msg.paths, msg.headings)
                except InstanceError as exc:
                    raise CommandError(ErrorCode.BAD_REQUEST, exc.public) from None
                e.executor = None
                e.problem = problem
                self._loaded()
                return f"loaded a plan for {len(msg.paths)} robots"
            case Start():
                self._run(e.current_run.start)
                return "started"
            case Pause():
                if e.status not in ("running", "replanning"):
                    raise CommandError(ErrorCode.BAD_STATE, f"cannot pause while {e.status}")
                self._set_paused(True)
                return "paused"
            case Resume():
                if not e.paused:
                    raise CommandError(ErrorCode.BAD_STATE, f"cannot resume while {e.status}")
                self._set_paused(False)
                return "resumed"
            case ReplanNow():
                return self._run(e.current_run.replan_now)
            case StopShift():
                return self._run(e.current_run.stop)
            case SetPolicy():
                e.policy_name, e.policy_seed = msg.policy, msg.seed
                e.current_run.policy_changed(replace=True)
                e.status_changed()
                return f"policy {e.policy_name}"
            case SetThreshold():
                e.threshold_ms = msg.threshold_ms
                e.current_run.policy_changed(replace=False)
                e.status_changed()
                return f"threshold {e.threshold_ms} ms"
            case SetSpeed():
                e.clock.set_speed(msg.speed)
                if e.journal is not None and e.current_run.active:
                    e.journal.append(SpeedRecord(speed=msg.speed))
                for w in e.worlds:
                    w.send(SetSpeed, speed=msg.speed)
                e.status_changed()
                return f"speed {msg.speed}"
            case PlaceIntruder():
                if not e.worlds:
                    raise CommandError(ErrorCode.BAD_STATE, "no world connection to place it")
                if e.problem is not None and not e.problem.instance.grid.is_free(msg.cell):
                    raise CommandError(ErrorCode.BAD_REQUEST, f"{msg.cell} is not a free cell")
                for w in e.worlds:
                    w.send(PlaceIntruder, cell=msg.cell, duration_ms=msg.duration_ms)
                return f"intruder sent to {len(e.worlds)} world connection(s)"
            case GetSnapshot():
                if isinstance(reply, Session):
                    e.send_snapshot(reply)
                    return None
                return "snapshot"
        raise CommandError(ErrorCode.FORBIDDEN, f"{msg.type} is not an operator command")

    @staticmethod
    def _run(order: Callable[[], T]) -> T:
        """Carry out an order to the run; its refusal is the command's (bad state)."""
        try:
            return order()
        except RunRefused as exc:
            raise CommandError(ErrorCode.BAD_STATE, str(exc)) from None

    def _set_paused(self, paused: bool) -> None:
        e = self._engine
        e.paused = paused
        e.current_run.set_paused(paused)
        for gs in e.robots.values():
            gs.set_paused(paused)
            e.flush(gs)
        e.status_changed()

    def load(self, problem: Problem, reply: Reply = None, ref: str | None = None) -> None:
        """Plan ``problem`` (unless it has a plan) and make it the loaded one."""
        e = self._engine
        e.executor = None
        if problem.plan is not None:
            e.problem = problem
            self._loaded()
            reply_to(reply, ref, None, "loaded")
            return
        e.planning = True
        e.status_changed()
        inst, motion = problem.instance, e.config.motion
        starts = inst.starts if motion == "omni" else inst.turning_starts(
            e.config.start_heading)
        e.solvers.spawn("load", problem, starts, inst.goals, reply, ref, motion)

    def load_solved(self, item: SolverDone) -> None:
        """The planner answered a load: make its plan the loaded one, or refuse the load."""
        e = self._engine
        e.planning = False
        assert item.problem is not None
        if isinstance(item.result, Plan):
            e.problem = replace(item.problem, plan=item.result)
            reply_to(item.reply, item.ref, None,
                     f"loaded {item.problem.map_name}: {len(item.result.paths)} robots, "
                     f"SOC {item.result.soc}, makespan {item.result.makespan}")
            self._loaded()
        else:
            reply_to(item.reply, item.ref, ErrorCode.BAD_REQUEST,
                     f"no plan for this instance: {item.result}")
            e.status_changed()

    def _loaded(self) -> None:
        e = self._engine
        for gs in e.robots.values():
            gs.new_run()
            gs.pose = None  # where it stood in the previous world
        e.feed.slack_series.clear()
        e.summary = None
        e.status_changed()
        for op in e.feed.operators:
            e.send_snapshot(op)
        self.maybe_autostart()

    def maybe_autostart(self) -> None:
        """Start the loaded run if ``autostart`` is on and all its robots are connected."""
        e = self._engine
        if not e.config.autostart or e.status != "loaded":
            return
        e.current_run.autostart()
