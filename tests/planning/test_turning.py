"""The ``turning`` motion model: headings, distance tables, plans and their JSON, the validator.

CBS and the other planners under ``turning`` are in ``test_turning_cbs.py``.
"""

from __future__ import annotations

import itertools
from collections import deque

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from gateway.planning.distance import distance_tables, turning_distance_tables
from gateway.planning.grid import Cell, Grid
from gateway.planning.instance import Instance
from gateway.planning.motion import (
    DEFAULT_START_HEADING,
    HeadedCell,
    parse_heading,
    turning_step,
)
from gateway.planning.plan import Plan
from gateway.planning.solution_json import SolutionJson
from gateway.planning.validate import check_plan, plan_violations
from tests.planning.exhaustive import FORWARD, optimal_soc
from tests.planning.support_planning import grid_of
from tests.planning.test_validate import _brute_force_valid


def test_parse_heading_accepts_numbers_and_names() -> None:
    assert [parse_heading(w) for w in ("0", "south", "W", " North ")] == [0, 1, 2, 3]
    with pytest.raises(ValueError, match="bad heading 'up'"):
        parse_heading("up")
    assert DEFAULT_START_HEADING == 0  # east, as the LoRR start kit; documented in README


@pytest.mark.parametrize(("a", "b", "legal"), [
    ((1, 1, 0), (1, 1, 0), True),    # wait
    ((1, 1, 0), (1, 1, 1), True),    # clockwise: east -> south
    ((1, 1, 0), (1, 1, 3), True),    # counter-clockwise: east -> north
    ((1, 1, 0), (1, 1, 2), False),   # half turn in one step
    ((1, 1, 0), (2, 1, 0), True),    # forward east (+x)
    ((1, 1, 1), (1, 2, 1), True),    # forward south (+y)
    ((1, 1, 2), (0, 1, 2), True),    # forward west
    ((1, 1, 3), (1, 0, 3), True),    # forward north (-y)
    ((1, 1, 0), (0, 1, 0), False),   # backwards
    ((1, 1, 0), (1, 2, 0), False),   # sideways
    ((1, 1, 0), (2, 1, 1), False),   # move and turn at once
    ((1, 1, 0), (3, 1, 0), False),   # two cells
])
def test_turning_step(a: HeadedCell, b: HeadedCell, legal: bool) -> None:
    assert turning_step(a, b) is legal


def test_turning_distances_by_hand() -> None:
    # Corridor of 3; goal (2,0). Facing east: 2 moves. Facing south: a turn, then 2 moves.
    # Facing west: two turns, then 2 moves. On the goal: 0 whatever the heading.
    grid = grid_of("...")
    table = turning_distance_tables(grid, [(2, 0)])[0]
    assert [int(table[4 * 0 + h]) for h in range(4)] == [2, 3, 4, 3]
    assert [int(table[4 * 2 + h]) for h in range(4)] == [0, 0, 0, 0]
    # A fixed goal heading (north) costs the turn(s) at the end.
    fixed = turning_distance_tables(grid, [(2, 0)], [3])[0]
    assert [int(fixed[4 * 0 + h]) for h in range(4)] == [3, 4, 5, 4]
    assert [int(fixed[4 * 2 + h]) for h in range(4)] == [1, 2, 1, 0]
    with pytest.raises(ValueError, match="not a free cell"):
        turning_distance_tables(grid_of(".@."), [(1, 0)])


def _forward_bfs(grid: Grid, start: HeadedCell, goal: Cell, heading: int | None) -> int:
    """Timesteps from ``start`` to the goal by a plain BFS over poses (-1 if unreachable)."""
    seen = {start}
    queue = deque([(start, 0)])
    while queue:
        (x, y, h), d = queue.popleft()
        if (x, y) == goal and heading in (None, h):
            return d
        dx, dy = FORWARD[h]
        nxt = [(x, y, (h + 1) % 4), (x, y, (h + 3) % 4)]
        if grid.is_free((x + dx, y + dy)):
            nxt.append((x + dx, y + dy, h))
        for p in nxt:
            if p not in seen:
                seen.add(p)
                queue.append((p, d + 1))
    return -1


@settings(max_examples=40, deadline=None)
@given(arrays(bool, st.tuples(st.integers(1, 5), st.integers(1, 6)),
              elements=st.sampled_from([True, True, True, False])), st.data())
def test_turning_distance_tables_match_a_forward_search(free: np.ndarray,
                                                        data: st.DataObject) -> None:
    free = free.copy()
    free.flat[0] = True
    grid = Grid(free)
    cells = list(grid.free_cells())
    goals = data.draw(st.lists(st.sampled_from(cells), min_size=1, max_size=3, unique=True))
    headings = data.draw(st.lists(st.sampled_from([None, 0, 1, 2, 3]), min_size=len(goals),
                                  max_size=len(goals)))
    tables = turning_distance_tables(grid, goals, headings)
    omni = distance_tables(grid, goals)
    for k, (goal, heading) in enumerate(zip(goals, headings, strict=True)):
        for c in cells:
            for h in range(4):
                got = int(tables[k, 4 * grid.index(c) + h])
                assert got == _forward_bfs(grid, (*c, h), goal, heading)
                # the omni distance is a lower bound of the turning one; both see the same cells
                assert (got >= 0) == (omni[k, grid.index(c)] >= 0)
                assert got >= omni[k, grid.index(c)]
    blocked = [4 * i + h for i in range(grid.size) if not free.flat[i] for h in range(4)]
    assert all(tables[:, s].tolist() == [-1] * len(goals) for s in blocked)


def test_many_goals_are_searched_in_chunks() -> None:
    grid = grid_of("......", "..@...", "......", "......")
    goals = list(grid.free_cells())  # more than one chunk of 16
    tables = turning_distance_tables(grid, goals)
    for k in (0, 17, len(goals) - 1):
        assert tables[k].tolist() == turning_distance_tables(grid, [goals[k]])[0].tolist()


def test_turning_plan_costs_count_turns_but_not_trailing_waits() -> None:
    plan = Plan.of_poses([[(0, 0, 0), (1, 0, 0), (1, 0, 1), (1, 0, 1)],  # turn on goal: 2
                          [(2, 1, 2), (2, 1, 2), (2, 1, 2)]])              # already there: 0
    assert plan.motion == "turning"
    assert plan.paths == (((0, 0), (1, 0), (1, 0)), ((2, 1),))
    assert plan.headings == ((0, 0, 1), (2,))
    assert (plan.soc, plan.makespan) == (2, 2)
    assert plan.heading(0, 9) == 1 and plan.position(0, 9) == (1, 0)
    assert plan.poses(0) == ((0, 0, 0), (1, 0, 0), (1, 0, 1))
    assert Plan.of([[(0, 0), (1, 0)]]).motion == "omni"
    with pytest.raises(ValueError, match="no headings"):
        Plan.of([[(0, 0)]]).poses(0)
    with pytest.raises(ValueError, match="one heading per path entry"):
        Plan((((0, 0), (1, 0)),), ((0,),))


def test_solution_paths_round_trip_through_json() -> None:
    turning = Plan.of_poses([[(0, 0, 0), (0, 0, 1), (0, 1, 1)], [(2, 2, 3)]])
    assert turning.json_paths() == [[[0, 0, 0], [0, 0, 1], [0, 1, 1]], [[2, 2, 3]]]
    assert Plan.from_json("turning", turning.json_paths()) == turning
    omni = Plan.of([[(0, 0), (0, 1)]])
    assert omni.json_paths() == [[[0, 0], [0, 1]]]
    assert Plan.from_json("omni", omni.json_paths()) == omni


@pytest.mark.parametrize(("motion", "paths", "message"), [
    ("diagonal", [], "motion must be"),
    ("turning", {}, "paths must be a list"),
    ("turning", [[]], "agent 0: path must be a non-empty list"),
    ("turning", [[[0, 0]]], r"agent 0 t=0: \[0, 0\] is not \[x, y, heading\] of integers"),
    ("omni", [[[0, 0], [0, 0, 1]]], r"agent 0 t=1: \[0, 0, 1\] is not \[x, y\] of integers"),
    ("turning", [[[0, 0, 4]]], "agent 0 t=0: heading 4 is not 0-3"),
    ("turning", [[[0, 0, True]]], "is not"),
])
def test_malformed_solution_paths_are_rejected(motion: str, paths: object,
                                               message: str) -> None:
    with pytest.raises(ValueError, match=message):
        Plan.from_json(motion, paths)


def test_instance_start_headings_default_and_override() -> None:
    grid = grid_of("...", "...")
    inst = Instance(grid, ((0, 0), (2, 1)), ((2, 0), (0, 1)))
    assert inst.turning_starts() == ((0, 0, 0), (2, 1, 0))
    assert inst.turning_starts(3) == ((0, 0, 3), (2, 1, 3))
    given_headings = Instance(grid, inst.starts, inst.goals, start_headings=(1, 2))
    assert given_headings.turning_starts(3) == ((0, 0, 1), (2, 1, 2))
    with pytest.raises(ValueError, match="2 starts but 1 start headings"):
        Instance(grid, inst.starts, inst.goals, start_headings=(1,))
    with pytest.raises(ValueError, match="0-3"):
        Instance(grid, inst.starts, inst.goals, start_headings=(1, 5))


OPEN3 = grid_of("...", "...", "...")


def test_valid_turning_plan() -> None:
    # Agent 0 drives east along the middle row; agent 1 turns south (clockwise), waits for
    # agent 0 to clear (1,1) a full step, then drives down.
    starts: list[HeadedCell] = [(0, 1, 0), (1, 0, 0)]
    goals: list[Cell | HeadedCell] = [(2, 1), (1, 2, 1)]
    plan = Plan.of_poses([[(0, 1, 0), (1, 1, 0), (2, 1, 0)],
                          [(1, 0, 0), (1, 0, 1), (1, 0, 1), (1, 1, 1), (1, 2, 1)]])
    assert plan_violations(OPEN3, starts, goals, plan) == []
    check_plan(OPEN3, starts, goals, plan)


@pytest.mark.parametrize(("poses", "message"), [
    ([(0, 0, 0), (0, 1, 0)], "agent 0 t=1: (0, 0, 0) -> (0, 1, 0) is not a wait, a 90-degree "
                             "turn or one cell forward"),
    ([(0, 0, 0), (0, 0, 2), (0, 1, 2)], "agent 0 t=1: (0, 0, 0) -> (0, 0, 2) is not a wait"),
    ([(0, 0, 1), (1, 0, 1)], "agent 0: path starts with heading 1, its start heading is 0"),
    ([(0, 0, 0), (0, 0, 1), (0, 1, 1), (0, 1, 0)],
     "agent 0: path ends with heading 0, its goal heading is 1"),
    ([(0, 0, 0), (0, 0, 7)], "agent 0 t=1: heading 7 is not 0-3"),
    ([(0, 0, 0), (1, 0, 0), (1, 0, 1), (1, 1, 1)], "agent 0 t=3: (1, 1) is not a free cell"),
])
def test_bad_turning_paths(poses: list[HeadedCell], message: str) -> None:
    grid = grid_of("...", ".@.")
    goal = (poses[-1][0], poses[-1][1], 1) if "goal heading" in message else poses[-1][:2]
    found = plan_violations(grid, [(0, 0, 0)], [goal], Plan.of_poses([poses]))
    assert any(v.startswith(message) for v in found), found


def test_a_turning_robot_holds_its_cell() -> None:
    # Agent 0 turns on (1,0) at t=1 and back at t=2, then drives on at t=3. Agent 1 entering
    # (1,0) while it turns is a vertex conflict; entering at t=3, right after it left, a
    # following conflict; at t=4 it is fine.
    strip = grid_of("....")
    starts, goals = [(1, 0, 0), (0, 0, 0)], [(3, 0), (1, 0)]
    turner = [(1, 0, 0), (1, 0, 1), (1, 0, 0), (2, 0, 0), (3, 0, 0)]

    def entering_at(t: int) -> list[str]:
        follower = [(0, 0, 0)] * t + [(1, 0, 0)]
        return plan_violations(strip, starts, goals, Plan.of_poses([turner, follower]))

    assert entering_at(2)[0] == "vertex conflict: agents 0 and 1 at (1, 0) at t=2"
    assert entering_at(3) == ["following conflict (not 1-robust): agent 1 is at (1, 0) at t=3, "
                              "where agent 0 was at t=2"]
    assert entering_at(4) == []


def _literal_turning_valid(grid: Grid, starts: list[HeadedCell], goals: list[Cell],
                           paths: list[list[HeadedCell]]) -> bool:
    """DESIGN section 2 read literally for ``turning``: the start pose, legal steps, then the
    omni definition on the cells (a legal turning step is a wait or a 4-neighbour move)."""
    for k, p in enumerate(paths):
        if p[0] != starts[k]:
            return False
        for (x, y, h), (x2, y2, h2) in itertools.pairwise(p):
            dx, dy = FORWARD[h]
            if not (((x, y) == (x2, y2) and (h2 - h) % 4 != 2)
                    or (x2, y2, h2) == (x + dx, y + dy, h)):
                return False
    return _brute_force_valid(grid, [(x, y) for x, y, _ in starts], goals,
                              [[(x, y) for x, y, _ in p] for p in paths])


@st.composite
def _random_turning_plans(
        draw: st.DrawFn) -> tuple[list[HeadedCell], list[Cell], list[list[HeadedCell]]]:
    """Random walks of mostly legal steps (some illegal), so that many plans are nearly
    valid."""
    n = draw(st.integers(1, 3))
    pose = st.tuples(st.integers(0, 2), st.integers(0, 2), st.integers(0, 3))
    paths = []
    for _ in range(n):
        path = [draw(pose)]
        for step in draw(st.lists(st.sampled_from("wlrffx"), max_size=5)):
            x, y, h = path[-1]
            dx, dy = FORWARD[h]
            path.append({"w": (x, y, h), "l": (x, y, (h + 3) % 4), "r": (x, y, (h + 1) % 4),
                         "f": (x + dx, y + dy, h), "x": (x + dy, y + dx, h)}[step])
        paths.append(path)
    starts = [p[0] for p in paths]
    goals = [p[-1][:2] if draw(st.booleans()) else draw(pose)[:2] for p in paths]
    return starts, goals, paths


@settings(max_examples=300, deadline=None)
@given(_random_turning_plans())
def test_turning_validator_agrees_with_the_definition_read_literally(
        case: tuple[list[HeadedCell], list[Cell], list[list[HeadedCell]]]) -> None:
    starts, goals, paths = case
    g = grid_of("...", ".@.", "...")
    plan = Plan(tuple(tuple(q[:2] for q in p) for p in paths),
                tuple(tuple(q[2] for q in p) for p in paths))
    assert (plan_violations(g, starts, goals, plan) == []) == _literal_turning_valid(
        g, starts, goals, paths)


def test_oracle_turning_by_hand() -> None:
    # One agent in a corridor of 3, to (2,0): facing east 2, facing west 4 (two turns first);
    # with the goal heading fixed to north, one more turn at the end.
    grid = grid_of("...")
    assert optimal_soc(grid, [(0, 0, 0)], [(2, 0)]) == 2
    assert optimal_soc(grid, [(0, 0, 2)], [(2, 0)]) == 4
    assert optimal_soc(grid, [(0, 0, 0)], [(2, 0, 3)]) == 3
    # Corridor of 4: A (0,0) east -> (2,0); B (1,0) facing west -> (3,0). B turns twice (t=1,
    # 2), is on (2,0) at t=3 and (3,0) at t=4: cost 4. A may enter (1,0) only at t=4 (B held
    # it until t=2, and t=3 follows B's departure... B was there at t=2, so not at t=3), and
    # reaches (2,0) at t=5. SOC 9 (omni: 5, test_exhaustive).
    assert optimal_soc(grid_of("...."), [(0, 0, 0), (1, 0, 2)], [(2, 0), (3, 0)]) == 9


def test_solution_json_writes_and_reads_turning_plans() -> None:
    plan = Plan.of_poses([[(0, 0, 0), (0, 0, 1), (0, 1, 1)], [(2, 1, 2), (1, 1, 2)]])
    written = SolutionJson("m.map", ((0, 0, 0), (2, 1, 2)), ((0, 1), (1, 1)), plan, True,
                           0.5, 3).to_json()
    assert written["motion"] == "turning"
    assert [a["start"] for a in written["agents"]] == [[0, 0, 0], [2, 1, 2]]
    assert written["agents"][0]["path"] == [[0, 0, 0], [0, 0, 1], [0, 1, 1]]
    assert (written["soc"], written["makespan"]) == (3, 2)
    read = SolutionJson.from_json(written)
    assert (read.plan, read.starts, read.goals) == (plan, ((0, 0, 0), (2, 1, 2)),
                                                     ((0, 1), (1, 1)))
    omni = SolutionJson("m.map", ((0, 0),), ((0, 1),), Plan.of([[(0, 0), (0, 1)]]), True, 0.1,
                        0).to_json()
    assert omni["motion"] == "omni" and SolutionJson.from_json(omni).plan.motion == "omni"
