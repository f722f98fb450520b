"""Operator commands, and the run lifecycle they drive: load, start, pause, replan, settings.

The engine hands every operator command (from an operator's connection, or from inside the
process with a future to answer) to :meth:`OperatorCommands.handle`; it checks the command
against the gateway's status, changes the run, and answers ``ok`` or ``error`` with a code.
A load that needs the planner is answered when the plan comes back
(:meth:`OperatorCommands.load_solved`). What the executor says in return goes back through
the engine's routing.
"""

from __future__ import annotations

import time
from dataclasses import replace
from typing import TYPE_CHECKING

from gateway.execution.actions import ActionDurations
from gateway.execution.oneshot.executor import ExecutionError
from gateway.planning.movingai import format_map
from gateway.planning.plan import Plan
from gateway.runtime.journal import PolicyRecord, RunRecord, SpeedRecord, new_run_id
from gateway.server.items import Reply, SolverDone
from gateway.server.planner import (
    InstanceError,
    Problem,
    problem_from_paths,
    resolve_instance,
    without_paths,
)
from gateway.server.runs.resume import executor_for
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
)

if TYPE_CHECKING:
    from gateway.server.engine import Engine

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

    def __init__(self, engine: Engine) -> None:
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
        if e.lifelong is not None:
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
                self.start()
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
                if e.lifelong is not None and not e.paused:
                    try:
                        e.lifelong.executor.plan_now(e.now_ms())
                    except ExecutionError as exc:
                        raise CommandError(ErrorCode.BAD_STATE, str(exc)) from None
                    e.lifelong.route()
                    return "planning a window now"
                if e.executor is None or e.paused:
                    raise CommandError(ErrorCode.BAD_STATE, f"cannot replan while {e.status}")
                try:
                    e.executor.request_replan(e.now_ms())
                except ExecutionError as exc:
                    raise CommandError(ErrorCode.BAD_STATE, str(exc)) from None
                e.route(e.executor.drain())
                return "replanning"
            case SetPolicy():
                e.policy_name, e.policy_seed = msg.policy, msg.seed
                self._policy_changed(replace=True)
                e.status_changed()
                return f"policy {e.policy_name}"
            case SetThreshold():
                e.threshold_ms = msg.threshold_ms
                if e.lifelong is not None:
                    e.lifelong.executor.set_threshold(msg.threshold_ms)
                self._policy_changed(replace=False)
                e.status_changed()
                return f"threshold {e.threshold_ms} ms"
            case SetSpeed():
                e.clock.set_speed(msg.speed)
                if e.journal is not None and (e.executor is not None or e.lifelong is not None):
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

    def _policy_changed(self, *, replace: bool) -> None:
        """Give the running executor the operator's policy (or threshold), journaled."""
        e = self._engine
        ex = e.executor
        if ex is not None:
            ex.set_policy(PolicyRecord(
                policy=e.policy_name, policy_seed=e.policy_seed, threshold_ms=e.threshold_ms,
                replace=replace, makespan_lb_ms=ex.plan.makespan * e.config.action_ms))

    def _set_paused(self, paused: bool) -> None:
        e = self._engine
        e.paused = paused
        if e.lifelong is not None:
            e.lifelong.set_paused(paused)
        ex = e.executor
        if ex is not None and ex.paused != paused:
            (ex.pause if paused else ex.resume)(e.now_ms())
            e.route(ex.drain())
        for gs in e.robots.values():
            gs.set_paused(paused)
            e.flush(gs)
        e.status_changed()

    def _durations(self, robots: int) -> list[ActionDurations]:
        """Each robot's t_x per action kind: its configured model, else ``action_ms``."""
        cfg = self._engine.config
        models = {name: ActionDurations(m.move_ms, m.turn_ms, m.wait_ms)
                  for name, m in cfg.robot_models.items()}
        uniform = ActionDurations.uniform(cfg.action_ms)
        return [models[cfg.robot_model[k]] if k in cfg.robot_model else uniform
                for k in range(robots)]

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
        if e.lifelong is not None:
            if e.all_online(e.lifelong.robots):
                e.lifelong.start()
            return
        if e.problem is not None and e.all_online(e.problem.instance.num_agents):
            self.start()

    def start(self) -> None:
        """Start executing the loaded plan (or the lifelong shift) from time 0."""
        e = self._engine
        if e.lifelong is not None:
            if e.status != "loaded":
                raise CommandError(ErrorCode.BAD_STATE, f"cannot start while {e.status}")
            e.lifelong.start()
            return
        if e.problem is None or e.problem.plan is None or e.status not in ("loaded", "done"):
            raise CommandError(ErrorCode.BAD_STATE, f"cannot start while {e.status}")
        plan = e.problem.plan
        for gs in e.robots.values():
            gs.new_run()
        e.summary = None
        e.solvers.solver_ms = 0.0
        e.finished_event.clear()
        e.paused = False
        e.feed.new_run()
        cfg = e.config
        e.runs += 1
        journal = e.journal
        # a journaled run's id never repeats (random); without a journal, the first run of
        # the process has none and later ones are numbered
        e.run_id = new_run_id() if journal is not None else (
            "" if e.runs == 1 else str(e.runs))
        run = RunRecord(
            run_id=e.run_id, wall_start_s=0.0, speed=e.clock.speed,
            map_name=e.problem.map_name, map_text=format_map(e.problem.instance.grid),
            paths=[list(p) for p in plan.paths],
            headings=None if plan.headings is None else [list(h) for h in plan.headings],
            policy=e.policy_name, policy_seed=e.policy_seed, threshold_ms=e.threshold_ms,
            makespan_lb_ms=plan.makespan * cfg.action_ms, action_ms=cfg.action_ms,
            drop_waits=cfg.drop_waits, max_replans=cfg.max_replans,
            lookahead=cfg.dispatch_lookahead,
            durations=[(d.move_ms, d.turn_ms, d.wait_ms)
                       for d in self._durations(len(plan.paths))],
            # what the blocks of the earlier runs lasted (the gateway learns across runs)
            block_history=e.block_history[-100:])
        e.executor = executor_for(run, journal.append if journal is not None else None,
                                  e.feed.record)
        e.block_history = e.executor.blocks.history  # grows as this run's blocks clear
        for hook in e.before_start:
            hook()
        e.clock.reset()  # time 0 is now: building the ADG and the GC pass are not charged
        if journal is not None:  # the plan boundary: the previous run's records go
            e.run_record = run.model_copy(update={"wall_start_s": time.time()})
            journal.begin_run(e.run_record)
        e.executor.start(0.0)
        e.status_changed()
        e.route(e.executor.drain())
