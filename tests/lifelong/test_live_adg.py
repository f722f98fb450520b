"""The appendable ADG: what it refuses, and its estimates across appended segments."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from gateway.execution.errors import ExecutionError
from gateway.execution.lifelong.live_adg import FORWARD, LiveADG
from gateway.planning.grid import Grid
from gateway.planning.pibt import StateSpace, WindowedPIBT
from tests.lifelong.support import small_problem

LINE = Grid(np.ones((1, 5), dtype=bool))  # cells 0..4 in a row


def test_refuses_following_swaps_and_jumps() -> None:
    adg = LiveADG(LINE, [0, 1])
    with pytest.raises(ExecutionError, match="not 1-robust"):
        adg.append([[0, 1], [1, 2]])  # robot 0 follows robot 1 into cell 1
    with pytest.raises(ExecutionError, match="vertex conflict"):
        adg.append([[0, 1], [1, 1]])
    with pytest.raises(ExecutionError, match="jumps"):
        adg.append([[0, 1], [0, 3]])
    with pytest.raises(ExecutionError, match="committed end states"):
        adg.append([[1, 0], [1, 0]])
    assert adg.n_pending() == 0  # nothing was appended
    adg.append([[0, 1], [0, 2], [1, 3]])  # 1-robust: robot 0 enters 1 a step after 1 left
    assert adg.end_cell == [1, 3]
    entering = adg.queue[0][0]
    assert (entering.kind, entering.cell, entering.dep_robot, entering.dep_seq) == (
        FORWARD, 1, 1, 0)


def test_turning_moves_only_along_the_heading() -> None:
    adg = LiveADG(LINE, [0], [0])
    with pytest.raises(ExecutionError, match="off its heading"):
        adg.append([[0], [1]], [[0], [1]])
    with pytest.raises(ExecutionError, match="180"):
        adg.append([[0], [0]], [[0], [2]])
    adg.append([[0], [1], [1]], [[0], [0], [1]])  # forward east, then turn to south
    assert [a.kind for a in adg.queue[0]] == [FORWARD, 1]


def test_dependency_spans_segments() -> None:
    """A cell left in one segment and entered in a later one: the entry waits for the leave."""
    adg = LiveADG(LINE, [1, 3])
    adg.append([[1, 3], [2, 3]])  # robot 0 leaves 1
    adg.append([[2, 3], [2, 4], [2, 4]])
    adg.append([[2, 4], [3, 4]])  # robot 0 enters 3, which robot 1 left in the last segment
    assert adg.is_ready(1)  # robot 1's move into 4 depends on nobody
    last = adg.queue[0][-1]
    assert (last.cell, last.dep_robot, last.dep_seq) == (3, 1, 0)
    adg.finish(0)
    assert not adg.is_ready(0)  # robot 1 has not left cell 3 yet
    adg.finish(1)
    assert adg.is_ready(0)


def _execute(adg: LiveADG, k: int, now: int, delayed: dict[int, int]) -> dict[tuple[int, int], int]:
    """Tick-by-tick execution (each action k ticks; robot r idle until ``delayed[r]``);
    the completion time of every action as (robot, seq) -> tick + 1."""
    n = adg.n_robots
    progress = [0] * n
    done: dict[tuple[int, int], int] = {}
    t = now
    while adg.n_pending():
        starting = [progress[r] == 0 and t >= delayed.get(r, 0) and adg.is_ready(r)
                    for r in range(n)]
        for r in range(n):
            if progress[r] or starting[r]:
                progress[r] += 1
                if progress[r] == k:
                    done[(r, adg.done[r])] = t + 1
                    adg.finish(r)
                    progress[r] = 0
        t += 1
        assert t < now + 10_000, "deadlock"
    return done


@settings(max_examples=10, deadline=None)
@given(seed=st.integers(0, 1000), turning=st.booleans(), k=st.integers(1, 3),
       delayed_robot=st.integers(0, 7), delay=st.integers(0, 9))
def test_estimates_are_exact_without_unknown_delays(seed: int, turning: bool, k: int,
                                                    delayed_robot: int, delay: int) -> None:
    """Three appended PIBT windows; Algorithm 1 over the whole graph (with one known delay)
    predicts every completion of the tick-by-tick execution exactly."""
    problem = small_problem(seed, robots=8, size=10)
    space = StateSpace(problem.grid, turning)
    planner = WindowedPIBT(space, 8, seed=seed)
    adg = LiveADG(problem.grid, problem.starts, [0] * 8 if turning else None)
    goals = [list(problem.tasks[r]) for r in range(8)]
    for _ in range(3):
        states = [space.state(adg.end_cell[r], adg.end_heading[r]) for r in range(8)]
        win = planner.plan(states, goals, 4)
        cells = [[space.cell_of[s] for s in row] for row in win.states]
        heads = [[space.heading_of(s) for s in row] for row in win.states] if turning else None
        adg.append(cells, heads)
    est = adg.estimate(0, [0.0] * 8, [float(k)] * 3,
                       [delay if r == delayed_robot else 0 for r in range(8)])
    done = _execute(adg, k, 0, {delayed_robot: delay})
    for r in range(8):
        for i, tc in enumerate(est[r]):
            assert done[(r, i)] == tc


def test_held_robot_moves_after_its_hold() -> None:
    """A robot held for two steps waits through them, then drives on; the other one, free
    from the start, plans around it (1-robust, so the ADG accepts the window)."""
    grid = Grid(np.ones((2, 5), dtype=bool))  # cells 0..4 over 5..9
    space = StateSpace(grid, turning=False)
    planner = WindowedPIBT(space, 2, seed=1)
    win = planner.plan([0, 9], [[4], [5]], 6, hold=[2, 0])
    path0 = [row[0] for row in win.states]
    assert path0 == [0, 0, 0, 1, 2, 3, 4]
    assert [row[1] for row in win.states][1] != 9  # robot 1 is not held: it moves at once
    LiveADG(grid, [0, 9]).append([list(row) for row in win.states])


def test_retract_takes_back_what_waits_on_it() -> None:
    """Robot 1 follows robot 0 along the line: taking back robot 0's moves takes back robot
    1's too (they wait on them), both end where they stand, and a new window's entry into a
    cell depends on the new leaver, not on an action taken back."""
    adg = LiveADG(LINE, [1, 0])
    adg.append([[1, 0], [2, 0], [3, 1], [4, 2]])
    assert [len(q) for q in adg.queue] == [3, 2]
    assert adg.retract([0, 5], [1, 0]) == [0, 0]
    assert adg.end_cell == [1, 0] and adg.appended == [0, 0] and adg.n_pending() == 0
    adg.append([[1, 0], [1, 0], [2, 0], [2, 1]])  # robot 0 leaves 1 again, robot 1 enters
    entering = adg.queue[1][0]
    assert (entering.cell, entering.dep_robot, entering.dep_seq) == (1, 0, 0)


def test_retract_keeps_started_work_and_repairs_leavers() -> None:
    """Robot 0 drives 1 -> 2 -> 1 -> 2 and keeps only its started first move: cell 1's last
    leaver becomes that kept move again (not its third move, taken back), so robot 1's new
    entry into cell 1 waits on the kept move; nothing taken back, nothing changes."""
    adg = LiveADG(LINE, [1, 0])
    adg.append([[1, 0], [2, 0], [1, 0], [2, 0]])
    assert adg.retract([1, 5], [1, 0]) == [1, 0]
    assert adg.end_cell == [2, 0] and adg.appended == [1, 0]
    adg.append([[2, 0], [2, 1], [3, 1]])
    entering = adg.queue[1][0]
    assert (entering.cell, entering.dep_robot, entering.dep_seq) == (1, 0, 0)
    assert adg.retract([5, 5], [1, 0]) == [2, 1]  # nothing to take back: unchanged
    assert adg.n_pending() == 3


@settings(max_examples=15, deadline=None)
@given(seed=st.integers(0, 10_000), turning=st.booleans(), k=st.integers(1, 3),
       p_delay=st.sampled_from([0.0, 0.1, 0.4]), exact=st.booleans(), retract=st.booleans())
def test_appending_while_executing_stays_acyclic_and_collision_free(
        seed: int, turning: bool, k: int, p_delay: float, exact: bool, retract: bool) -> None:
    """Windows planned from the committed end states (held for the backlog) and appended while
    the fleet executes under random delays (``retract``: before each window, a random share of
    the actions not started is taken back): every dependency points to an earlier action (the
    graph is acyclic), and no two robots ever hold a cell at the same tick (a moving robot
    holds both cells of its move); with exact turning tables or the cells' lower bound."""
    n = 8
    problem = small_problem(seed, robots=n, size=10)
    rng = np.random.default_rng(seed)
    space = StateSpace(problem.grid, turning, exact=exact)
    planner = WindowedPIBT(space, n, seed=seed)
    adg = LiveADG(problem.grid, problem.starts, [0] * n if turning else None)
    goals = [list(problem.tasks[r]) for r in range(n)]
    cell = list(problem.starts)
    heading = [0] * n
    progress = [0] * n
    for t in range(120):
        if t % 4 == 0:
            if retract:
                keep = [(progress[r] > 0) + int(rng.integers(0, 3)) for r in range(n)]
                kept = adg.retract(keep, cell, heading)
                assert all(kept[r] >= (progress[r] > 0) for r in range(n))  # started stay
                goals = [list(problem.tasks[r]) for r in range(n)]
            states = [space.state(adg.end_cell[r], adg.end_heading[r]) for r in range(n)]
            hold = [adg.pending(r) - 1 for r in range(n)]
            win = planner.plan(states, goals, 3, hold)
            adg.append([[space.cell_of[s] for s in row] for row in win.states],
                       [[space.heading_of(s) for s in row] for row in win.states]
                       if turning else None)
            for r in range(n):
                del goals[r][:len(win.reached[r])]
                goals[r] = goals[r] or [int(c) for c in rng.choice(problem.tasks[r], 1)]
            for r in range(n):
                for a in adg.queue[r]:
                    if a.dep_robot >= 0 and adg.done[a.dep_robot] <= a.dep_seq:
                        dep = adg.queue[a.dep_robot][a.dep_seq - adg.done[a.dep_robot]]
                        assert dep.order < a.order
        delayed = rng.random(n) < p_delay
        starting = [progress[r] == 0 and not delayed[r] and adg.is_ready(r) for r in range(n)]
        held: dict[int, int] = {}
        for r in range(n):
            cells = {cell[r]}
            if progress[r] or starting[r]:
                head = adg.head(r)
                assert head is not None
                cells.add(head.cell)
            for c in cells:
                assert held.setdefault(c, r) == r, f"robots {held[c]} and {r} hold {c} at {t}"
        for r in range(n):
            if progress[r] or starting[r]:
                progress[r] += 1
                if progress[r] == k:
                    done = adg.finish(r)
                    cell[r], heading[r] = done.cell, done.heading
                    progress[r] = 0


def test_a_robot_on_its_last_goal_decides_first() -> None:
    """Robots 0 and 1 both want the centre of a 3 x 3 room next: robot 1, on its task's last
    goal, gets it although robot 0 has waited longer for its next goal (robot 0 still has two
    goals: it would win on time alone)."""
    grid = Grid(np.ones((3, 3), dtype=bool))  # 0 1 2 / 3 4 5 / 6 7 8
    for goals, winner in (([[5, 0], [7]], 1), ([[5], [7]], 0)):
        planner = WindowedPIBT(StateSpace(grid, turning=False), 2, seed=3)
        planner.elapsed[0] = 10
        win = planner.plan([3, 1], goals, 1)
        assert win.states[1][winner] == 4, goals


@pytest.mark.parametrize(("width", "turn"), [(4, True), (2, True), (4, False)])
def test_a_robot_turns_towards_a_held_cell_only_if_it_is_left(width: int, turn: bool) -> None:
    """Robot 0 faces north on the west end of a 1-row corridor and must turn east towards
    cell 1, held by robot 1 (facing east, goal at the east end). In a corridor of 4 cells
    robot 1 moves on, so robot 0 turns at once with ``turn_to_leaving`` (it enters cell 1 a
    timestep later, 1-robust), and waits without; in one of 2 cells robot 1 cannot leave
    (asked to, it turns in place), so robot 0 waits."""
    grid = Grid(np.ones((1, width), dtype=bool))
    space = StateSpace(grid, turning=True)
    planner = WindowedPIBT(space, 2, seed=1, turn_to_leaving=turn)
    planner.elapsed[0] = 10  # robot 0 decides first and asks robot 1 to move
    north, east = 3, 0
    win = planner.plan([space.state(0, north), space.state(1, east)], [[width - 1], [width - 1]],
                       2)
    first = win.states[1]
    if width == 4 and turn:
        assert first == [space.state(0, east), space.state(2, east)]
        assert win.states[2][0] == space.state(1, east)
    else:
        assert first[0] == space.state(0, north)
        assert space.cell_of[first[1]] == (2 if width == 4 else 1)  # it leaves if it can
