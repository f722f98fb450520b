"""A one-shot run inside the gateway: a loaded plan executed from time 0 to its end.

:class:`OneShotRun` is the :class:`~gateway.server.runs.base.Run` of the engine when it is not
running a shift. The plan loaded (``problem``) and the run's executor (a
:class:`~gateway.server.runs.resume.JournaledExecutor`) stay readable on the engine; this
class decides what they do: the run's start (a journaled :class:`RunRecord`, the plan
boundary), its ticks, pause, "replan now", the policy and threshold changes, the planner's
answers (a replan, a shadow plan) and the journal's compaction at each adopted plan, and its
rebuild from the journal after a restart (:meth:`OneShotRun.resume`).
"""

from __future__ import annotations

import logging
from typing import cast

from gateway.execution.actions import ActionDurations
from gateway.execution.core import Core
from gateway.execution.errors import ExecutionError
from gateway.execution.lifelong.tasks import TaskPool
from gateway.execution.oneshot.executor import Mode
from gateway.planning.instance import Instance
from gateway.planning.movingai import format_map, parse_map
from gateway.planning.plan import Plan
from gateway.runtime.journal import PolicyRecord, RunRecord, SnapshotRecord, new_run_id
from gateway.runtime.trace import trace_line
from gateway.server.items import SolverDone
from gateway.server.planner import Problem
from gateway.server.runs.base import RunContext, RunRefused
from gateway.server.runs.resume import (
    Carried,
    JournaledExecutor,
    Replayed,
    executor_for,
    plan_of,
    replay,
    snapshot_of,
)
from gateway.server.views import ShiftView
from protocol import Pose
from protocol.messages import HEADINGS, GatewayStatus, PolicyName

log = logging.getLogger("fleetgate.engine")


class OneShotRun:
    """The engine's loaded plan and its execution (see the module's docstring)."""

    def __init__(self, ctx: RunContext) -> None:
        self._ctx = ctx

    # ------------------------------------------------------------------ state
    @property
    def core(self) -> Core[object] | None:
        """The run's executor (None before the first start)."""
        return self._ctx.executor

    @property
    def tasks(self) -> TaskPool | None:
        """A one-shot run has no task pool."""
        return None

    @property
    def status(self) -> GatewayStatus:
        """empty, planning, loaded, running, paused, replanning or done."""
        ctx = self._ctx
        if ctx.planning:
            return "planning"
        ex = ctx.executor
        if ex is None:
            return "loaded" if ctx.problem is not None and ctx.problem.plan else "empty"
        if ex.mode is Mode.DONE:
            return "done"
        if ctx.paused:
            return "paused"
        if ex.mode in (Mode.STOPPING, Mode.SOLVING):
            return "replanning"
        return "running"

    @property
    def ticking(self) -> bool:
        """While the executor runs."""
        ex = self._ctx.executor
        return ex is not None and ex.mode is not Mode.DONE

    def _plan(self) -> Plan | None:
        ctx = self._ctx
        return ctx.executor.plan if ctx.executor is not None else (
            ctx.problem.plan if ctx.problem is not None else None)

    @property
    def turning(self) -> bool:
        """Whether the plan has headings."""
        plan = self._plan()
        return plan is not None and plan.headings is not None

    @property
    def plan_id(self) -> int | None:
        """The plan being executed."""
        ex = self._ctx.executor
        return ex.plan_id if ex else None

    @property
    def planner_busy(self) -> bool:
        """A replan under way (stopping or solving), or a shadow solve."""
        ex = self._ctx.executor
        return ex is not None and (ex.mode in (Mode.STOPPING, Mode.SOLVING)
                                   or ex.shadow_pending)

    @property
    def loads_plans(self) -> bool:
        """Operators load instances and plans into a one-shot run."""
        return True

    @property
    def active(self) -> bool:
        """Once a run was started."""
        return self._ctx.executor is not None

    @property
    def shift_view(self) -> ShiftView | None:
        """Not a shift."""
        return None

    def pose(self, robot: int) -> Pose | None:
        """The robot's first cell (and heading) of the plan."""
        plan = self._plan()
        if plan is None or robot >= len(plan.paths):
            return None
        heading = None if plan.headings is None else HEADINGS[plan.headings[robot][0]]
        return Pose(cell=plan.paths[robot][0], heading=heading)

    # ------------------------------------------------------------------ driving
    def monitor_tick(self, now_ms: float) -> None:
        """Tick the executor (while paused the monitor is kept true; no policy is asked)."""
        ctx = self._ctx
        ex = ctx.executor
        if ex is None or ex.mode is Mode.DONE:
            return
        ex.tick(now_ms)
        slack = ex.monitor.fleet_slack()
        ctx.metrics.fleet_slack.set(slack)
        ctx.feed.slack(now_ms, slack)
        ctx.route(ex.drain())

    def route(self) -> None:
        """Route what the executor emitted."""
        ex = self._ctx.executor
        self._ctx.route(ex.drain() if ex is not None else [])

    def _durations(self, robots: int) -> list[ActionDurations]:
        """Each robot's t_x per action kind: its configured model, else ``action_ms``."""
        cfg = self._ctx.config
        models = {name: ActionDurations(m.move_ms, m.turn_ms, m.wait_ms)
                  for name, m in cfg.robot_models.items()}
        uniform = ActionDurations.uniform(cfg.action_ms)
        return [models[cfg.robot_model[k]] if k in cfg.robot_model else uniform
                for k in range(robots)]

    def start(self) -> None:
        """Start executing the loaded plan from time 0 (a new run id; journaled: the plan
        boundary, the previous run's records go)."""
        e = self._ctx
        if e.problem is None or e.problem.plan is None or e.status not in ("loaded", "done"):
            raise RunRefused(f"cannot start while {e.status}")
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
            e.run_record = run.model_copy(update={"wall_start_s": e.clock.wall_s()})
            journal.begin_run(e.run_record)
        e.executor.start(0.0)
        e.status_changed()
        e.route(e.executor.drain())

    def autostart(self) -> None:
        """Start once every robot of the loaded plan is online."""
        e = self._ctx
        if e.problem is not None and e.all_online(e.problem.instance.num_agents):
            self.start()

    def set_paused(self, paused: bool) -> None:
        """Pause or resume the executor."""
        e = self._ctx
        ex = e.executor
        if ex is not None and ex.paused != paused:
            (ex.pause if paused else ex.resume)(e.now_ms())
            e.route(ex.drain())

    def replan_now(self) -> str:
        """Have the executor stop the fleet and replan."""
        e = self._ctx
        if e.executor is None or e.paused:
            raise RunRefused(f"cannot replan while {e.status}")
        try:
            e.executor.request_replan(e.now_ms())
        except ExecutionError as exc:
            raise RunRefused(str(exc)) from None
        e.route(e.executor.drain())
        return "replanning"

    def stop(self) -> str:
        """A one-shot run ends with its plan: there is no shift to stop."""
        raise RunRefused("a one-shot run has no shift to stop: it ends with its plan")

    def policy_changed(self, *, replace: bool) -> None:
        """Give the running executor the operator's policy (or threshold), journaled."""
        e = self._ctx
        ex = e.executor
        if ex is not None:
            ex.set_policy(PolicyRecord(
                policy=e.policy_name, policy_seed=e.policy_seed, threshold_ms=e.threshold_ms,
                replace=replace, makespan_lb_ms=ex.plan.makespan * e.config.action_ms))

    def solver_done(self, item: SolverDone) -> None:
        """A replan's or a shadow solve's answer."""
        e = self._ctx
        ex = e.executor
        if item.purpose == "shadow":
            if ex is not None and ex.shadow_pending:  # (else a new run was started meanwhile)
                ex.shadow_solved(item.result if isinstance(item.result, Plan) else None,
                                 e.now_ms())
                e.route(ex.drain())
            return
        if ex is None or ex.mode is not Mode.SOLVING:
            return  # a new run was started meanwhile
        now = e.now_ms()
        if isinstance(item.result, Plan):
            lines = e.feed.trace_lines
            ex.adopt_plan(item.result, now, e.solvers.solver_ms)
            self._compact(ex, lines)
        else:
            log.warning("replan found no plan, keeping the old one: %s", item.result)
            ex.abandon_replan(now)
        e.route(ex.drain())

    def _compact(self, ex: JournaledExecutor, trace_lines: int) -> None:
        """A plan was just adopted (the fleet is idle): replace the journal's records by a
        snapshot. Its records so far are committed and the trace flushed first, so a crash
        at any point leaves a journal that rebuilds the run and a trace no shorter than the
        snapshot says (``trace_lines``: those before the adoption)."""
        e = self._ctx
        if e.journal is None or e.run_record is None:
            return
        e.commit()
        e.journal.compact(snapshot_of(e.run_record, ex, Carried(
            e.policy_name, e.policy_seed, e.threshold_ms, e.clock.speed,
            e.solvers.solver_ms, e.feed.intruders, e.feed.replan_marks,
            trace_lines)))

    def cancel(self) -> None:
        """Nothing runs off the loop but the engine's solver tasks."""

    # ------------------------------------------------------------------ resume
    def resume(self) -> bool:
        """Rebuild the journaled run, if there is one, and carry on with it (robots are
        re-synchronised by their ``hello``); True if it is not done."""
        e = self._ctx
        journal = e.journal
        if journal is None:
            return False
        records = list(journal.records())
        if not records or not isinstance(records[0], RunRecord | SnapshotRecord):
            return False
        run = records[0] if isinstance(records[0], RunRecord) else records[0].run
        e.run_record = run
        grid = parse_map(run.map_text, name=run.map_name)
        first = plan_of(run.paths, run.headings)
        e.problem = Problem(Instance(grid, tuple(p[0] for p in first.paths),
                                     tuple(p[-1] for p in first.paths), run.map_name),
                            run.map_name, first)
        e.run_id = run.run_id
        e.runs += 1
        trace: list[str] = []
        e.replayed_trace = trace

        def record(rec: dict[str, object]) -> None:
            e.feed.record(rec)
            trace.append(trace_line(rec))

        e.replaying = True
        try:
            done = replay(records, on_commands=e.route,
                          on_report=e.replayed_report, trace=record,
                          on_snapshot=self._snapshot_replayed)
        finally:
            e.replaying = False
        assert done is not None
        self._resumed(done, trace)
        return e.status != "done"

    def _snapshot_replayed(self, done: Replayed) -> None:
        """The journal starts with a snapshot: the replans before it, as operators saw them."""
        self._ctx.feed.replan_marks = done.replan_marks

    def _resumed(self, done: Replayed, trace: list[str]) -> None:
        e = self._ctx
        run, ex = done.run, done.executor
        e.executor = ex
        e.block_history = ex.blocks.history
        e.policy_name = cast(PolicyName, done.policy)
        e.policy_seed, e.threshold_ms = done.policy_seed, done.threshold_ms
        e.solvers.solver_ms = done.solver_ms
        e.paused = ex.paused
        e.feed.intruders = set(done.intruders)
        e.feed.resume_trace(trace, done.trace_lines)
        ex.set_record(e.feed.record)
        ex.sink = e.journal.append if e.journal is not None else None
        e.clock.set_speed(done.speed)
        away = (e.clock.wall_s() - run.wall_start_s) * 1000.0 * done.speed
        e.clock.reset(max(done.last_t_ms, away))
        log.info("resumed the journaled run", extra={
            "run": run.run_id, "records": done.records, "plan": ex.plan_id,
            "t_ms": round(e.clock.now_ms()), "status": e.status})
        if ex.mode is Mode.SOLVING and done.solve is not None:
            e.route([done.solve])
        if ex.shadow_pending and done.shadow is not None:
            e.route([done.shadow])
        e.status_changed()
