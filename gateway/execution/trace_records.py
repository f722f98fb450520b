"""The trace record format (DESIGN section 3): one builder per record type.

The executor produces the ``plan``, ``dispatch``, ``start``, ``finish``, ``blocked``,
``unblocked``, ``cancel``, ``refused`` and ``trigger`` records through its ``record`` callback;
the drivers add ``intruder`` records and the closing ``summary``. A sink is any callable taking
one record (:class:`gateway.runtime.trace.JsonlWriter` writes them to a file, ``list.append``
keeps them in memory). The independent checker (``tracecheck``) reads the format on its own, on
purpose.
"""

from __future__ import annotations

from collections.abc import Callable, Collection, Mapping, Sequence
from typing import Any

from gateway.planning.grid import Cell

Record = dict[str, Any]
TraceSink = Callable[[Record], None]

EVENT_TYPES = ("dispatch", "start", "finish", "blocked", "unblocked", "cancel", "refused")
"""Record types about one action of one robot."""


def plan_record(t_ms: float, plan: int, paths: Sequence[Sequence[Cell]],
                headings: Sequence[Sequence[int]] | None = None,
                durations_ms: Sequence[Mapping[str, float] | None] | None = None,
                skip: Collection[tuple[int, int]] = ()) -> Record:
    """``{"t_ms", "type": "plan", "plan", "agents": [{"path": [[x, y], ...]}]}``; a turning
    plan (``headings``) adds ``"motion": "turning"`` and has ``[x, y, heading]`` entries; an
    agent's ``durations_ms`` (``{"move", "turn", "wait"}``) is given where not None, and its
    ``skip`` (the path indices of the waits that are no actions, ascending) where ``skip``
    (``(robot, path index)`` pairs) has any of its waits."""
    agents: list[Record] = []
    for k, path in enumerate(paths):
        agent: Record = {"path": [[x, y] for x, y in path] if headings is None else
                         [[x, y, h] for (x, y), h in zip(path, headings[k], strict=True)]}
        if durations_ms is not None and durations_ms[k] is not None:
            agent["durations_ms"] = dict(durations_ms[k] or {})
        skipped = sorted(i for r, i in skip if r == k)
        if skipped:
            agent["skip"] = skipped
        agents.append(agent)
    record: Record = {"t_ms": t_ms, "type": "plan", "plan": plan, "agents": agents}
    if headings is not None:
        record["motion"] = "turning"
    return record


def event_record(t_ms: float, kind: str, plan: int, robot: int, action: int,
                 reason: str | None = None) -> Record:
    """``{"t_ms", "type": kind, "plan", "robot", "action"}`` for a kind of :data:`EVENT_TYPES`
    (and ``"reason"`` if given: why a robot refused the action)."""
    if kind not in EVENT_TYPES:
        raise ValueError(f"unknown event type {kind!r}; expected one of {EVENT_TYPES}")
    record: Record = {"t_ms": t_ms, "type": kind, "plan": plan, "robot": robot, "action": action}
    if reason is not None:
        record["reason"] = reason
    return record


def trigger_record(t_ms: float, policy: str, fleet_slack_ms: float) -> Record:
    """``{"t_ms", "type": "trigger", "policy", "fleet_slack_ms"}``: a replan was decided."""
    return {"t_ms": t_ms, "type": "trigger", "policy": policy, "fleet_slack_ms": fleet_slack_ms}


def reschedule_record(t_ms: float, plan: int, edges: Sequence[tuple[int, int, int, int]],
                      switches: Sequence[tuple[Cell, int, int]], gain_ms: float) -> Record:
    """``{"t_ms", "type": "reschedule", "plan", "edges": [[robot, action, robot2, action2],
    ...], "switches": [[[x, y], first, second], ...], "gain_ms"}``: the plan's Type 2 edges
    from now on (every one, tail first), the switches that made them (on cell ``[x, y]``
    robot ``first`` now passes before ``second``) and the estimated gain in SOC."""
    return {"t_ms": t_ms, "type": "reschedule", "plan": plan,
            "edges": [list(e) for e in edges],
            "switches": [[list(cell), first, second] for cell, first, second in switches],
            "gain_ms": gain_ms}


def intruder_record(t_ms: float, cell: Cell, state: str) -> Record:
    """``{"t_ms", "type": "intruder", "cell": [x, y], "state": "on"|"off"}``."""
    if state not in ("on", "off"):
        raise ValueError(f"intruder state must be 'on' or 'off', got {state!r}")
    return {"t_ms": t_ms, "type": "intruder", "cell": [cell[0], cell[1]], "state": state}


def summary_record(soc_ms: float, makespan_ms: float) -> Record:
    """The last line: ``{"type": "summary", "soc_ms", "makespan_ms"}``."""
    return {"type": "summary", "soc_ms": soc_ms, "makespan_ms": makespan_ms}
