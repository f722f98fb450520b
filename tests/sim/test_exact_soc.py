"""Without an intruder the simulated execution costs exactly what the plan says:
SOC = 1000 ms x plan SOC and makespan = 1000 ms x plan makespan, on the shipped lab instances
and on the planner benchmark's set (read from ../shared/maps when it is there)."""

from __future__ import annotations

from collections.abc import Callable
from functools import partial
from pathlib import Path

import pytest

from bench.planner import CpuDeadline, instances
from gateway.planning.instance import Instance, load_instance
from gateway.planning.plan import NoSolution, Plan
from gateway.planning.solver import solve
from gateway.runtime.deadline import WallDeadline
from gateway.runtime.mapstore import resolve
from sim_clients.des import SimConfig, run_simulation
from tracecheck import check_trace

SHARED_MAPS = Path(__file__).resolve().parents[2] / ".." / "shared" / "maps"
BENCH_CAP_S = 1.0
"""Per-instance planner limit on the benchmark set, in CPU seconds (other jobs on a shared
machine do not take it away, as they would wall time): instances it cannot solve that fast are
left out (the planner's own benchmark covers them); at least half of each map must solve."""


def assert_exact(inst: Instance, plan: Plan) -> None:
    records: list[dict[str, object]] = []
    result = run_simulation(SimConfig(inst.grid, plan, intruder=False, solver_time="zero",
                                      trace=records.append))
    assert result.soc_ms == 1000 * plan.soc, inst.name
    assert result.makespan_ms == 1000 * plan.makespan, inst.name
    report = check_trace(records)
    assert report.ok, (inst.name, report.errors[:3])
    assert report.actions_run == sum(len(p) - 1 for p in plan.paths)


@pytest.mark.parametrize("scen", [f"lab-random-{i}" for i in range(1, 6)])
@pytest.mark.parametrize("agents", [5, 10])
def test_lab_instances_execute_exactly(scen: str, agents: int) -> None:
    inst = load_instance(resolve("lab", "map"), resolve(scen, "scen"), agents)
    plan = solve(inst.grid, inst.starts, inst.goals, deadline=WallDeadline(60.0)).plan
    assert_exact(inst, plan)


def solved_exactly(loaders: list[Callable[[], Instance]], cap_s: float) -> int:
    """Plan each instance within ``cap_s`` of CPU time; check every plan found; return how
    many."""
    solved = 0
    for load in loaders:
        inst = load()
        try:
            plan = solve(inst.grid, inst.starts, inst.goals, deadline=CpuDeadline(cap_s)).plan
        except NoSolution:
            continue
        solved += 1
        assert_exact(inst, plan)
    return solved


def test_dense_lab_instances_execute_exactly() -> None:
    # 15 robots on the 14x10 lab: some take the planner long, so each gets a cap
    loaders: list[Callable[[], Instance]] = [
        partial(load_instance, resolve("lab", "map"), resolve(f"lab-random-{i}", "scen"), 15)
        for i in range(1, 6)]
    assert solved_exactly(loaders, 3.0) >= 3


def _by_map() -> dict[str, list[Callable[[], Instance]]]:
    out: dict[str, list[Callable[[], Instance]]] = {}
    if SHARED_MAPS.is_dir():
        for label, load in instances(SHARED_MAPS):
            out.setdefault(label, []).append(load)
    return out


@pytest.mark.skipif(not SHARED_MAPS.is_dir(), reason="../shared/maps is not there")
@pytest.mark.parametrize("label", ["random-32-32-20", "room-32-32-4", "arena"])
def test_benchmark_set_executes_exactly(label: str) -> None:
    loaders = _by_map()[label]
    solved = solved_exactly(loaders, BENCH_CAP_S)
    print(f"{label}: {solved} of {len(loaders)} planned within {BENCH_CAP_S} s and checked")
    assert solved >= len(loaders) // 2, f"only {solved} of {len(loaders)} solved in time"
