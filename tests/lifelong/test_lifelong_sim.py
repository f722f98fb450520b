"""Lifelong runs in virtual time, checked by the independent LoRR output checker."""

from __future__ import annotations

import dataclasses
import gc
import json
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from gateway.execution.lifelong.executor import PlanRequest, Segment, WindowPlanner
from gateway.execution.lifelong.tasks import SCHEDULERS
from gateway.planning.generators import warehouse_map
from gateway.planning.guidance import corridor_share
from gateway.planning.lorr import LorrProblem, random_problem, read_problem
from gateway.planning.movingai import format_map
from gateway.planning.pibt import exact_fits
from sim_clients.lifelong import (
    CORRIDOR_LANES,
    CORRIDORS,
    LifelongConfig,
    lorr_output,
    run_lifelong,
)
from tests.lifelong.support import small_problem
from tracecheck.lorr import check_output, read_free

SHARED = Path(__file__).resolve().parents[2] / ".." / "shared" / "lorr"


@settings(max_examples=12, deadline=None)
@given(seed=st.integers(0, 10_000), turning=st.booleans(), counter=st.integers(1, 3),
       p_delay=st.sampled_from([0.0, 0.05, 0.3]),
       scheduler=st.sampled_from(sorted(SCHEDULERS)), max_wait=st.sampled_from([None, 6, 30]),
       station_cap=st.sampled_from([None, 1]), lanes=st.sampled_from([0, 1, 4]),
       doors=st.sampled_from([0, 20]), turn=st.sampled_from([None, False, True]),
       lns=st.sampled_from([None, 0, 30]))
def test_no_robot_enters_a_held_cell_under_any_delays(seed: int, turning: bool, counter: int,
                                                      p_delay: float, scheduler: str,
                                                      max_wait: int | None,
                                                      station_cap: int | None,
                                                      lanes: int, doors: int,
                                                      turn: bool | None,
                                                      lns: int | None) -> None:
    """Random maps, tasks and delays, every scheduler with and without a (tight) fairness
    bound and a station cap, with and without lanes and one-way doors (turning), turns towards
    cells being left allowed or not (by default under one tick an action only), with and
    without LNS over the windows (by default under more ticks an action only): the checker
    replays the output and finds no shared cell; tasks get done and every finished task has an
    event per errand."""
    problem = small_problem(seed, counter=counter, p_delay=p_delay)
    cfg = LifelongConfig(problem, ticks=120, turning=turning, period=3,
                         planner_time="zero", scheduler=scheduler, max_wait=max_wait,
                         station_cap=station_cap, lanes=lanes if turning else 0,
                         doors=doors if turning else 0, turn_to_leaving=turn, lns=lns,
                         seed=seed)
    res = run_lifelong(cfg)
    out = lorr_output(cfg, res)
    assert check_output(out, read_free(format_map(problem.grid))) == 120
    finishing = [e for e in out["events"] if e[3] == len(problem.tasks[e[2] % len(problem.tasks)])]
    assert len(finishing) == res.finished
    if p_delay == 0.0 and counter == 1:
        assert res.finished > 0


def test_checker_catches_a_shared_cell() -> None:
    """The oracle can fail: two robots driving into the same cell at once."""
    free = [[True] * 3]
    out = {"agentMaxCounter": 1, "start": [[0, 0, "E"], [0, 2, "E"]],
           "actualPaths": ["[(0,0,0,0,0):(F 1,W 2)]", "[(0,0,2,0,0):(R 1,R 1,F 1)]"]}
    with pytest.raises(AssertionError, match="both hold"):
        check_output(out, free)
    out["actualPaths"][1] = "[(0,0,2,0,0):(R 1,R 1,W 1)]"  # stays: fine
    assert check_output(out, free) == 3


@pytest.mark.parametrize("enabled", [True, False])
def test_the_collector_is_off_inside_calls_only(monkeypatch: pytest.MonkeyPatch,
                                                enabled: bool) -> None:
    """Python's garbage collector never runs inside a planning call (a collection there cost a
    tick of latency), and the run leaves it as it found it, on or off."""
    seen: list[bool] = []

    class Recording(WindowPlanner):
        def __call__(self, req: PlanRequest) -> Segment:
            seen.append(gc.isenabled())
            return super().__call__(req)

    monkeypatch.setattr("sim_clients.lifelong.WindowPlanner", Recording)
    (gc.enable if enabled else gc.disable)()
    try:
        res = run_lifelong(LifelongConfig(small_problem(3), ticks=40, period=4))
        assert gc.isenabled() == enabled
    finally:
        gc.enable()
    assert len(seen) == res.calls > 0
    assert not any(seen)


def test_same_seed_same_run() -> None:
    """With the planner time charged as zero or fixed, a run is a function of its inputs."""
    problem = small_problem(3)
    runs = [run_lifelong(LifelongConfig(problem, ticks=80, period=4, planner_time=150.0))
            for _ in range(2)]
    assert runs[0].letters == runs[1].letters
    assert runs[0].events == runs[1].events


def test_tables_computed_ahead_change_no_decision() -> None:
    """Computing the robots' later errands' tables between calls only moves work: with the
    planner time charged as fixed, the run is the same with and without it, and each call
    is followed by one measured spell of it. (Not with tables guided by the crowd: a table
    computed ahead is searched with the crowd of the call before the one that would search
    it.)"""
    problem = small_problem(7)
    runs = [run_lifelong(LifelongConfig(problem, ticks=90, period=4, planner_time=150.0,
                                        warm=warm, crowd=False)) for warm in (True, False)]
    assert runs[0].letters == runs[1].letters and runs[0].events == runs[1].events
    assert len(runs[0].warm_times) == runs[0].calls and not runs[1].warm_times


def test_slow_planner_costs_throughput_but_not_safety() -> None:
    """A planner charged 2.5 s per call leaves robots idle between plans."""
    problem = dataclasses.replace(small_problem(5, p_delay=0.0), agent_counter=1)
    fast = run_lifelong(LifelongConfig(problem, ticks=150, period=5, planner_time="zero"))
    slow_cfg = LifelongConfig(problem, ticks=150, period=5, planner_time=2500.0)
    slow = run_lifelong(slow_cfg)
    assert slow.finished < fast.finished
    check_output(lorr_output(slow_cfg, slow), read_free(format_map(problem.grid)))


@pytest.mark.skipif(not SHARED.is_dir(), reason="../shared/lorr is absent")
def test_shared_maze_problem(tmp_path: Path) -> None:
    """The LoRR maze problem for 60 ticks through the CLI: valid output, tasks under way."""
    from gateway.cli import main

    problem = SHARED / "maze.domain" / "maze-example_40.json"
    out_path = tmp_path / "out.json"
    assert main(["lifelong", "--problem", str(problem), "--ticks", "90", "--output",
                 str(out_path), "--planner-time", "zero", "--no-progress"]) == 0
    out = json.loads(out_path.read_text())
    prob = read_problem(problem)
    assert out["teamSize"] == 40 and out["actionModel"] == "MAPF_T"
    assert check_output(out, read_free(format_map(prob.grid))) == 90
    assert out["events"]


def one_cell_aisles(robots: int, seed: int) -> LorrProblem:
    """Shelf blocks of 3 x 2 cells between aisles one cell wide (as on LoRR's warehouse_large),
    ``robots`` robots, delays."""
    grid = warehouse_map(4, 3, 3, shelf_depth=2, aisle=1, border=1, name="aisles")
    return dataclasses.replace(random_problem(grid, robots, seed, p_delay=0.05),
                               agent_counter=3)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_corridor_lanes_where_tables_are_over_the_cells(monkeypatch: pytest.MonkeyPatch,
                                                        seed: int) -> None:
    """A planner budget too small for exact tables (as 10,000 robots on warehouse_large are),
    on a map of one-cell aisles: the default run is the run with CORRIDOR_LANES (the lanes
    are on by default there, and change the run), and its output replays without a shared
    cell."""
    problem = one_cell_aisles(12, seed)
    budget = 2 * 12 * int(problem.grid.free.sum())  # the cells' tables fit, the states' not
    monkeypatch.setattr("sim_clients.lifelong.PLANNER_BUDGET", budget)
    assert corridor_share(problem.grid) >= CORRIDORS
    assert not exact_fits(problem.grid, 12, budget)
    runs = {lanes: run_lifelong(LifelongConfig(problem, ticks=150, period=10,
                                               planner_time="zero", lanes=lanes, seed=seed))
            for lanes in (None, CORRIDOR_LANES, 0)}
    assert runs[None].letters == runs[CORRIDOR_LANES].letters
    assert runs[None].letters != runs[0].letters  # the lanes change the run (these seeds)
    cfg = LifelongConfig(problem, ticks=150, period=10, planner_time="zero", seed=seed)
    assert check_output(lorr_output(cfg, runs[None]), read_free(format_map(problem.grid))) == 150
