"""What operators see: the fields of a ``snapshot`` message, built from a :class:`FleetView`,
the read model the engine hands over (this module knows nothing of the engine).

A lifelong shift has no plan up front: its snapshot (``lifelong`` true) shows the map, each
robot's committed path from where it stands (``paths[r]``, whose first step is the robot's
action number ``path_offsets[r]``; segments are appended as the shift goes, so a page follows
the ``finish`` events along it and the next snapshot extends it), its task and the task's
remaining errand cells (the next one first, also its ``goal``), and who waits for whom.
"""

from __future__ import annotations

import math
from collections.abc import Collection, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from gateway.execution.lifelong.executor import LifelongExecutor
from gateway.execution.lifelong.tasks import Task
from gateway.execution.oneshot.executor import Executor
from gateway.planning.grid import Cell, Grid
from gateway.planning.plan import Plan
from gateway.server.planner import Problem
from protocol import ActionCounts, Pose, ReplanMark, RobotView, WaitEdge
from protocol.gateway_session import GatewaySession
from protocol.messages import HEADINGS, GatewayStatus, Heading, PolicyName


@dataclass(frozen=True)
class FleetView:
    """The state a snapshot shows, read-only: the run (``problem``, ``executor``), the robots'
    protocol sessions, and the operator-facing settings and series."""

    t_ms: float
    """The present (the engine's time)."""
    max_replans: int
    status: GatewayStatus
    threshold_ms: float
    policy: PolicyName
    speed: float
    slack_series: Sequence[tuple[float, float]]
    intruders: Collection[Cell]
    replan_marks: Sequence[Mapping[str, Any]]
    problem: Problem | None
    executor: Executor | None
    robots: Mapping[int, GatewaySession]
    worlds: int = 0
    """World connections (they place intruders)."""
    shift: ShiftView | None = None
    """The lifelong shift (then ``problem`` and ``executor`` are None)."""


@dataclass(frozen=True)
class ShiftView:
    """A lifelong shift as operators see it: its map's name, its executor and its planning
    period (plan ms)."""

    name: str
    executor: LifelongExecutor
    period_ms: float


PATH_AHEAD = 24
"""Committed steps per robot a lifelong snapshot shows (a window is a few steps)."""


def _heading(pose: Pose | None, ex: Executor | None, plan: Plan | None,
             robot: int) -> Heading | None:
    """The robot's heading: as it reports it, else (turning) as the executor or the plan
    has it, else None (omni)."""
    if pose is not None and pose.heading is not None:
        return pose.heading
    h = ex.robot_heading(robot) if ex is not None else \
        plan.headings[robot][0] if plan is not None and plan.headings is not None else None
    return None if h is None else HEADINGS[h]


def map_rows(grid: Grid) -> list[str]:
    """The map as text rows: ``.`` free, ``@`` blocked (row y is ``rows[y]``)."""
    return ["".join("." if f else "@" for f in row) for row in grid.free.tolist()]


def snapshot_fields(view: FleetView) -> dict[str, Any]:
    """Everything a ``snapshot`` carries except msg_id/seq."""
    problem, ex = view.problem, view.executor
    out: dict[str, Any] = {
        # the clock stops with the run: a finished run's time is that of its last event
        "t_ms": 0.0 if ex is None else ex.now_ms if ex.done else view.t_ms,
        "max_replans": view.max_replans,
        "status": view.status,
        "threshold_ms": view.threshold_ms,
        "policy": view.policy,
        "speed": view.speed,
        "fleet_slack": list(view.slack_series),
        "intruders": sorted(view.intruders),
        "replan_marks": [ReplanMark(**m) for m in view.replan_marks],
        "worlds": view.worlds,
    }
    if view.shift is not None:
        sex = view.shift.executor
        t_ms = sex.now_ms if sex.done else view.t_ms if view.status != "loaded" else 0.0
        out.update(shift_fields(view.shift, view.robots), t_ms=t_ms,
                   tasks_per_min=throughput_per_min(sex.finished_tasks, t_ms),
                   period_ms=view.shift.period_ms)
        return out
    if problem is None:
        return out
    out["map_name"] = problem.map_name
    out["scen_name"] = problem.scen_name
    out["rows"] = map_rows(problem.instance.grid)
    plan = ex.plan if ex is not None else problem.plan
    if plan is not None:
        out["paths"] = [list(p) for p in plan.paths]
        if plan.headings is not None:
            out["headings"] = [list(h) for h in plan.headings]
    goals = problem.instance.goals
    counts = {"dispatched": 0, "running": 0, "blocked": 0, "finished": 0}
    robots = []
    for r in range(problem.instance.num_agents):
        rec = view.robots.get(r) or GatewaySession(r)
        path = plan.paths[r] if plan is not None else (problem.instance.starts[r],)
        # before a run, robots are shown on the instance's starts (what the run will use)
        cell = path[0] if ex is None else rec.pose.cell if rec.pose is not None else (
            ex.robot_cell(r))
        held = next(iter(rec.held.items()), None)
        for h in rec.held.values():
            counts[h.phase] += 1
        counts["finished"] += rec.next_index if ex is not None else 0
        robots.append(RobotView(
            robot_id=r, connected=rec.connected, cell=cell,
            heading=_heading(rec.pose if ex is not None else None, ex, plan, r),
            activity=rec.activity(), action_id=held[0] if held else None, goal=goals[r],
            remaining=list(path[min(rec.next_index, len(path) - 1):]),
            slack_ms=ex.monitor.robot_slack(r) if ex is not None else 0.0))
    out["robots"] = robots
    if ex is not None:
        total = sum(max(len(p) - 1, 0) for p in ex.plan.paths)
        pending = max(0, total - sum(counts.values()))
        out["actions"] = ActionCounts(pending=pending, **counts)
        out.update(plan=ex.plan_id, soc_ms=ex.soc_ms, makespan_ms=ex.makespan_ms,
                   est_soc_ms=ex.monitor.estimated_soc_ms(),
                   est_makespan_ms=ex.monitor.estimated_makespan_ms(),
                   replans=ex.replans,
                   waits=[WaitEdge(robot=a, action=b, for_robot=c, for_action=d)
                          for a, b, c, d in ex.monitor.blocking_edges()])
    return out


def _current_tasks(ex: LifelongExecutor) -> dict[int, Task]:
    """Each robot's current task: of those it holds, the one it got first."""
    out: dict[int, Task] = {}
    for task in ex.pool.tasks.values():
        r = task.robot
        if r >= 0 and (r not in out or (task.assigned_at, task.id) <
                       (out[r].assigned_at, out[r].id)):
            out[r] = task
    return out


def shift_fields(shift: ShiftView, sessions: Mapping[int, GatewaySession]) -> dict[str, Any]:
    """The snapshot fields of a lifelong shift (see the module doc)."""
    ex = shift.executor
    adg, cell_of = ex.adg, ex.grid.cell
    tasks = _current_tasks(ex)
    paths, headings, robots, waits = [], [], [], []
    counts = {"dispatched": 0, "running": 0, "blocked": 0, "finished": sum(adg.done)}
    pending = 0
    for r in range(ex.n):
        queue = adg.queue[r]
        ahead = [queue[i] for i in range(min(len(queue), PATH_AHEAD))]
        path = [cell_of(ex.cell[r]), *(cell_of(a.cell) for a in ahead)]
        paths.append(path)
        if ex.turning:
            headings.append([ex.heading[r], *(a.heading for a in ahead)])
        sent = ex.busy(r)
        pending += len(queue) - sent
        if sent < len(queue):  # its next action waits for another robot's
            a = queue[sent]
            if a.dep_robot >= 0 and adg.done[a.dep_robot] <= a.dep_seq:
                waits.append(WaitEdge(robot=r, action=adg.done[r] + sent,
                                      for_robot=a.dep_robot, for_action=a.dep_seq))
        rec = sessions.get(r) or GatewaySession(r)
        for h in rec.held.values():
            counts[h.phase] += 1
        held = next(iter(rec.held), None)
        task = tasks.get(r)
        errands = [cell_of(c) for c in task.errands[task.done:]] if task is not None else []
        robots.append(RobotView(
            robot_id=r, connected=rec.connected, cell=path[0],
            heading=HEADINGS[ex.heading[r]] if ex.turning else None,
            activity=rec.activity(), action_id=held, goal=errands[0] if errands else path[0],
            remaining=path, task=task.id if task is not None else None, errands=errands))
    return {
        "lifelong": True, "map_name": shift.name, "rows": map_rows(ex.grid), "plan": 0,
        "paths": paths, "headings": headings, "path_offsets": list(adg.done),
        "robots": robots, "actions": ActionCounts(pending=pending, **counts), "waits": waits,
    }


def throughput_per_min(finished: int, elapsed_ms: float) -> float:
    """Tasks per minute of plan time (0 before any time passed)."""
    return finished * 60_000.0 / elapsed_ms if elapsed_ms > 0 and math.isfinite(elapsed_ms) \
        else 0.0
