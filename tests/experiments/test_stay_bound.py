"""The stay bound: its savings tables against fresh runs, and its choice by hand."""

from __future__ import annotations

import dataclasses
import json

import pytest

from experiments.campaign import PlanTask, SimSettings, load_grid, plan_instance, variant_config
from experiments.stay_bound import GainTable, best_capture, gain_table, stay_grid
from experiments.stay_paths import Path, PathTable, best_path_capture, path_table
from gateway.execution.commands import SolveRequest
from gateway.execution.oneshot.executor import Mode
from gateway.execution.oneshot.policies import RandomReplan
from gateway.planning.plan import Plan
from gateway.runtime.mapstore import resolve
from sim_clients.des import SimConfig, Simulation, run_simulation
from sim_clients.intruder import IntruderState
from sim_clients.stays import StaySpec, parse_stay

SIM = SimSettings(solver_time="zero", intruder_stay="uniform:1-30")
MAP = str(resolve("lab", "map"))


class _Assuming(Simulation):
    """A fresh run (no memo, no fork) whose replan keeps the intruder's cell free until its
    robot's need plus ``assumed_ms``: the test's own reading of the table's entries."""

    assumed_ms = 0.0

    def plan_for(self, request: SolveRequest, now: float) -> tuple[Plan | None, float]:
        intr = self.intruder
        assert intr is not None
        if intr.state in (IntruderState.WAITING, IntruderState.PRESENT) \
                and intr.cell not in request.starts:
            assert intr.cell is not None and intr.config.stay_ms is not None
            until = max(now + 1.0, intr.leave_ms - intr.config.stay_ms + self.assumed_ms)
            request = dataclasses.replace(request, obstacles=((intr.cell, until),))
        return super().plan_for(request, now)


def _fixed(config: SimConfig, stay: float) -> SimConfig:
    return dataclasses.replace(config, intruder_stay=StaySpec("fixed", (stay,)))


def test_every_entry_of_a_table_equals_fresh_runs() -> None:
    rec = plan_instance(PlanTask("lab", MAP, 5, 0, 0, 20.0))
    config = variant_config(load_grid(MAP), rec.plan, 1154091980, "intruder", SIM)
    stays, assumed = (2.0, 12.0), (4.0, 20.0)
    got = gain_table(config, ("lab", 5, 0, 1154091980), stays, assumed, step_ms=2000.0)
    assert got.need_ms is not None and got.actions
    assert {a for _, a in got.actions} == set(assumed)
    for k, stay in enumerate(stays):
        none = run_simulation(_fixed(config, stay)).soc_ms
        for (t, a), savings in got.actions.items():
            sim = _Assuming(dataclasses.replace(_fixed(config, stay), max_replans=1,
                                                informed=True))
            sim.assumed_ms = 1000.0 * a
            sim.executor.policy = RandomReplan(0, intruder_appear_ms=t, makespan_lb_ms=0.0)
            res = sim.run()
            # a policy replans only while the intruder is there: else it saves nothing
            watch = Simulation(dataclasses.replace(_fixed(config, stay), policy="none"))
            watch.start()
            watch.run_until(t)
            gone = watch.finished() or watch.intruder is None \
                or watch.intruder.state is IntruderState.GONE
            assert savings[k] == (0.0 if gone else none - res.soc_ms)
    assert any(max(c, 0.0) > 0 for c in got.clairvoyant)
    assert GainTable.from_json(json.loads(json.dumps(got.to_json()))) == got


def _table(need: float, clair: tuple[float, ...],
           actions: dict[tuple[float, float], tuple[float, ...]]) -> GainTable:
    return GainTable(("m", 1, 0, 0), need, clair, actions)


def test_the_budgeted_choice_by_hand() -> None:
    # A: a replan that saves 10 s at both stays (never loses); B: one that loses 10 s at the
    # short stay and saves 20 s at the long one (expected 5 s, worse with chance 1/2).
    a = _table(5000.0, (10e3, 10e3), {(5000.0, 1.0): (10e3, 10e3)})
    b = _table(5000.0, (0.0, 20e3), {(5000.0, 1.0): (-10e3, 20e3)})
    # clairvoyant: 10 s + 10 s expected; no budget: A only
    none = best_capture([a, b], 0.0)
    assert (none.capture, none.worse, none.never_losing) == (0.5, 0.0, 0.5)
    assert none.clairvoyant_ms == 10e3
    # a budget of 1/4 (half an experiment of two) buys B: (10 + 5) / 20
    full = best_capture([a, b], 0.25)
    assert (full.capture, full.worse, full.median) == (0.75, 0.25, 0.75)
    # an eighth buys half of B (the linear program mixes): (10 + 2.5) / 20
    half = best_capture([a, b], 0.125)
    assert half.capture == pytest.approx(0.625) and half.worse == pytest.approx(0.125)


def test_replans_before_the_block_is_seen_count_only_from_t_a() -> None:
    early = _table(5000.0, (10e3, 10e3), {(3000.0, 1.0): (10e3, 10e3),
                                           (6000.0, 1.0): (4e3, 4e3)})
    assert best_capture([early], 0.0, None).capture == 1.0  # from T_a: the early replan
    assert best_capture([early], 0.0, 0.0).capture == 0.4  # from the report: the later one
    assert best_capture([early], 0.0, 2000.0).capture == 0.0  # from 2 s after: none


def test_stay_grid_is_the_quantile_midpoints() -> None:
    grid = stay_grid(parse_stay("uniform:0-10"), 5)
    assert grid == pytest.approx((1.0, 3.0, 5.0, 7.0, 9.0), abs=0.05)
    assert stay_grid(parse_stay("fixed:4"), 3) == (4.0, 4.0, 4.0)


class _Switching(_Assuming):
    """A fresh run for a path table's entry: its replans assume ``assumed_ms``; once the
    intruder is gone, a replan knows it (no obstacle)."""

    def plan_for(self, request: SolveRequest, now: float) -> tuple[Plan | None, float]:
        intr = self.intruder
        assert intr is not None
        if intr.state is IntruderState.GONE:
            request = dataclasses.replace(request, obstacles=())
        return super().plan_for(request, now)


def _follow(config: SimConfig, path: Path, end: float, back: bool) -> float:
    """The SOC of a fresh run that takes ``path``'s switches while the block lasts (each only
    if the fleet runs then) and, with ``back``, replans back at the first tick from ``end``
    the fleet runs (keeping its plan if it never does within 10 s)."""
    sim = _Switching(dataclasses.replace(config, max_replans=3, informed=True))
    sim.start()
    for t, a in path:
        if t >= end:
            break
        sim.run_until(t)
        if sim.finished() or sim.executor.mode is not Mode.RUNNING:
            break
        sim.assumed_ms = 1000.0 * a
        sim.replan_now(t)
    t = end
    while back and t <= end + 10_000.0:
        sim.run_until(t)
        if not sim.finished() and sim.executor.mode is Mode.RUNNING:
            sim.replan_now(t)
            break
        t += 100.0
    sim.run_until(None)
    return sim.result().soc_ms


def test_every_path_of_a_path_table_equals_fresh_runs() -> None:
    rec = plan_instance(PlanTask("lab", MAP, 5, 0, 0, 20.0))
    config = variant_config(load_grid(MAP), rec.plan, 1154091980, "intruder", SIM)
    stays, assumed = (2.0, 9.0), (4.0, 12.0)
    got = path_table(config, ("lab", 5, 0, 1154091980), stays, assumed, (0.0, 0.0),
                     step_ms=2000.0, second_step_ms=2000.0)
    assert max(len(p) for p in got.paths) == 2 and got.need_ms == 5000.0
    for k, stay in enumerate(stays):
        fixed = _fixed(config, stay)
        none = run_simulation(fixed).soc_ms
        end = got.need_ms + 1000.0 * stay
        for path, savings in got.paths.items():
            best = min(_follow(fixed, path, end, False), _follow(fixed, path, end, True))
            assert savings[k] == none - best, (stay, path)
    # a decision after the block ended is not taken: the path saves what its prefix saves
    late = [p for p in got.paths if p and p[0][0] >= got.need_ms + 2000.0]
    assert late and all(got.paths[p][0] == got.paths[()][0] for p in late)
    # what bench/stay_frontier.py reads back is what bench/stay_bound.py wrote
    assert PathTable.from_json(json.loads(json.dumps(got.to_json()))) == got


def test_the_paths_choice_reads_only_paths_within_the_switches() -> None:
    one = PathTable(("m", 1, 0, 0), 5000.0, (10e3, 10e3),
                    {(): (0.0, 0.0), ((5000.0, 1.0),): (5e3, 5e3),
                     ((5000.0, 1.0), (7000.0, 2.0)): (10e3, 10e3)})
    assert best_path_capture([one], 0.0, 1) == (0.5, 0.0, 0.5)
    assert best_path_capture([one], 0.0, 2) == (1.0, 0.0, 1.0)
