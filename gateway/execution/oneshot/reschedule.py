"""Reschedule-first: let others pass a delayed robot by switching Type 2 edges (sans-I/O).

The Type 2 edges of an ADG follow from the order in which the robots visit each cell. A
*visit* is a robot's stay on a cell: it begins with the move that enters the cell (none for
the cell a robot starts on) and ends with the move that leaves it (none for its goal). The
plan visits every cell in time order; from any order the Type 2 edges follow by the ADG's own
rule: from the move ending each visit to the move beginning the next visit of each other robot
(:meth:`Schedule.edges`; on the plan's order these are exactly the ADG's edges).

A *switch* swaps two adjacent visits of different robots on one cell, as the switchable
edges of Berndt et al. (SADG) and Feng et al. (switchable TPG) do: the later robot passes
first, and the edge from the first robot's leaving move to the second's entering move becomes
one from the second's leaving move to the first's entering move. A switch keeps the schedule
1-robust-safe (each cell's visits stay totally ordered, consecutive visits of different
robots separated by an edge that waits for the earlier robot to have left), so it is allowed
only when both visits can still move: the first robot has not been sent its entering move
(it may gain a dependency), and the second's visit has an end (a goal visit is last). A
switch that would make the graph cyclic (a deadlock) is refused by :meth:`ADG.with_type2`.

:func:`improve` searches switches greedily: at each round it tries the switches of the
edges that make a robot wait now (their tail's estimated completion decides the head's start,
largest waits first), scores each by the monitor's Algorithm 1 estimate of the sum of
completion times on the switched graph (:meth:`Monitor.rewired`), keeps the best if it gains,
and stops when no switch gains. Algorithm 1 assumes a late action ends now, so letting a robot
pass a delayed one would never seem to pay; the estimate therefore holds what the fleet
reported (:meth:`Monitor.with_holds`, the executor's choice): a robot waiting for a blocked
cell until the block's expected end, an action running late by ``e`` for ``e`` more.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

from gateway.execution.errors import ExecutionError
from gateway.execution.oneshot.adg import ADG
from gateway.execution.oneshot.monitor import NOT_STARTED, Monitor
from gateway.planning.grid import Cell


@dataclass(frozen=True, slots=True)
class Visit:
    """One robot's stay on a cell: its entering and leaving move (vertex ids, -1: none)."""

    robot: int
    enter: int
    """The move into the cell; -1 if the robot starts on it."""
    leave: int
    """The move out of the cell; -1 if it is the robot's goal."""


def _cell_edges(visits: tuple[Visit, ...]) -> list[tuple[int, int]]:
    """The Type 2 edges of one cell's visit order: from each visit's leaving move to the
    entering move of each other robot's next visit."""
    out = []
    for i, first in enumerate(visits):
        if first.leave < 0:
            continue
        seen = {first.robot}
        for later in visits[i + 1:]:
            if later.robot not in seen:
                seen.add(later.robot)
                out.append((first.leave, later.enter))
    return out


class Schedule:
    """The order of the robots' visits of each cell (only cells two robots visit)."""

    def __init__(self, orders: dict[Cell, tuple[Visit, ...]],
                 edges: dict[Cell, list[tuple[int, int]]] | None = None) -> None:
        self.orders = orders
        self._edges = edges if edges is not None else \
            {c: _cell_edges(v) for c, v in orders.items()}

    @staticmethod
    def of(adg: ADG) -> Schedule:
        """The plan's own order (by entering step): the schedule of ``adg``'s edges."""
        per_cell: dict[Cell, list[tuple[int, Visit]]] = {}
        for k in range(adg.n_robots):
            lo, hi = adg.first[k], adg.first[k + 1]
            enter, since = -1, -1
            cell = adg.src[lo] if lo < hi else None
            for v in range(lo, hi):
                if adg.src[v] == adg.dst[v]:
                    continue
                per_cell.setdefault(adg.src[v], []).append((since, Visit(k, enter, v)))
                enter, since, cell = v, adg.step_of[v], adg.dst[v]
            if cell is not None:
                per_cell.setdefault(cell, []).append((since, Visit(k, enter, -1)))
        orders = {}
        for c, got in per_cell.items():
            if len({v.robot for _, v in got}) > 1:
                got.sort(key=lambda sv: sv[0])
                orders[c] = tuple(v for _, v in got)
        return Schedule(orders)

    def edges(self) -> list[tuple[int, int]]:
        """Every Type 2 edge (tail, head) the order implies."""
        return [e for cell_edges in self._edges.values() for e in cell_edges]

    def switchable(self, cell: Cell, index: int) -> bool:
        """True if visits ``index`` and ``index + 1`` of ``cell`` may change places (by the
        visits alone: two robots, the first one enters, the second one leaves)."""
        visits = self.orders[cell]
        first, second = visits[index], visits[index + 1]
        return first.robot != second.robot and first.enter >= 0 and second.leave >= 0

    def switched(self, cell: Cell, index: int) -> Schedule:
        """The schedule with visits ``index`` and ``index + 1`` of ``cell`` swapped."""
        if not self.switchable(cell, index):
            raise ExecutionError(f"visits {index} and {index + 1} of {cell} cannot switch")
        visits = list(self.orders[cell])
        visits[index], visits[index + 1] = visits[index + 1], visits[index]
        orders, edges = dict(self.orders), dict(self._edges)
        orders[cell] = tuple(visits)
        edges[cell] = _cell_edges(orders[cell])
        return Schedule(orders, edges)


@dataclass(frozen=True)
class Rescheduled:
    """A better schedule :func:`improve` found, with its graph and monitor."""

    schedule: Schedule
    adg: ADG
    monitor: Monitor
    switches: tuple[tuple[Cell, int, int], ...]
    """Each switch as (cell, robot that now passes first, robot that now waits)."""
    gain_ms: float
    """How much earlier the estimate says the fleet finishes (sum of completion times)."""


def _candidates(schedule: Schedule, monitor: Monitor,
                may_gain_edges: Callable[[int], bool], limit: int) -> list[tuple[Cell, int]]:
    """The switchable pairs whose edge makes its head wait now, largest wait first."""
    found: list[tuple[float, Cell, int]] = []
    snap = monitor.snapshot()
    ts, tc, adg = snap.ts, snap.tc, monitor.adg
    for cell, visits in schedule.orders.items():
        for i in range(len(visits) - 1):
            first, second = visits[i], visits[i + 1]
            if not schedule.switchable(cell, i) or not may_gain_edges(first.enter) \
                    or monitor.state(second.enter) != NOT_STARTED:
                continue
            if first.leave < 0:
                continue
            head, tail = second.enter, first.leave
            own = monitor.release_ms[second.robot] if adg.is_first[head] else tc[head - 1]
            wait = tc[tail] - own
            if wait > 0 and tc[tail] >= ts[head]:
                found.append((wait, cell, i))
    found.sort(key=lambda f: -f[0])
    return [(c, i) for _, c, i in found[:limit]]


def gains_edges(old: ADG, new: ADG) -> list[int]:
    """The vertices with a Type 2 predecessor in ``new`` they do not have in ``old``."""
    out = []
    for v in range(new.n_vertices):
        got = new.t2_pred[new.t2_pred_ptr[v]:new.t2_pred_ptr[v + 1]]
        had = old.t2_pred[old.t2_pred_ptr[v]:old.t2_pred_ptr[v + 1]]
        if got != had and not set(got) <= set(had):
            out.append(v)
    return out


Search = Callable[[Schedule, ADG, Monitor, Callable[[int], bool], dict[int, float]],
                  "Rescheduled | None"]
"""``(schedule, adg, monitor, may_gain_edges, holds) -> better schedule or None``: how the
executor looks for switches (:func:`improve`; tests pass random ones)."""


def improve(schedule: Schedule, adg: ADG, monitor: Monitor,
            may_gain_edges: Callable[[int], bool], holds: dict[int, float], *,
            min_gain_ms: float = 1.0, rounds: int = 4,
            candidates: int = 8) -> Rescheduled | None:
    """Greedy switches that the estimate says make the fleet finish earlier (see the module),
    or None if none does. ``may_gain_edges(v)`` says whether vertex ``v`` may still get a
    new dependency (it has not been dispatched); the estimate holds each vertex ``v`` of
    ``holds`` (a robot waiting for a blocked cell) until ``holds[v]``
    (:meth:`Monitor.with_holds`). The returned monitor has no holds."""
    base = monitor.with_holds(holds) if holds else monitor
    best_soc = base.estimated_soc_ms()
    start_soc = best_soc
    switches: list[tuple[Cell, int, int]] = []
    current: ADG | None = None
    sched, graph, mon = schedule, adg, base
    for _ in range(rounds):
        picked: tuple[float, Schedule, ADG, Monitor, tuple[Cell, int, int]] | None = None
        for cell, i in _candidates(sched, mon, may_gain_edges, candidates):
            trial = sched.switched(cell, i)
            try:
                trial_adg = graph.with_type2(trial.edges())
            except ExecutionError:
                continue  # a cycle
            if not all(may_gain_edges(v) for v in gains_edges(graph, trial_adg)):
                continue
            trial_mon = mon.rewired(trial_adg)
            soc = trial_mon.estimated_soc_ms()
            if soc < best_soc - min_gain_ms and (picked is None or soc < picked[0]):
                visits = sched.orders[cell]
                picked = (soc, trial, trial_adg, trial_mon,
                          (cell, visits[i + 1].robot, visits[i].robot))
        if picked is None:
            break
        best_soc, sched, graph, mon, switch = picked
        switches.append(switch)
        current = graph
    if current is None:
        return None
    return Rescheduled(sched, graph, monitor.rewired(graph), tuple(switches),
                       start_soc - best_soc)
