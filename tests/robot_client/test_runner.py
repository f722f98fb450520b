"""The action runner driving a pty-simulated Kobuki through the real driver and odometry."""

from __future__ import annotations

import math
from collections.abc import Iterator

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from robot_client.floor import HEADING_ANGLE, FloorGrid, heading_of_step
from robot_client.odometry import Pose, wrap_angle
from robot_client.runner import ActionRunner, GridAction
from tests.robot_client.floor_render import FloorRenderer
from tests.robot_client.rig import PtyRig

FLOOR = FloorGrid(width=5, height=4, cell_m=0.4, tag_size_m=0.12)
POS_TOL = 0.012
HEADING_TOL = math.radians(4)


@pytest.fixture
def rig_factory() -> Iterator[list[PtyRig]]:
    rigs: list[PtyRig] = []
    yield rigs
    for r in rigs:
        r.close()


def make(rigs: list[PtyRig], *args: object, **kwargs: object) -> PtyRig:
    rig = PtyRig(FLOOR, *args, **kwargs)  # type: ignore[arg-type]
    rigs.append(rig)
    return rig


def at(rig: PtyRig, cell: tuple[int, int]) -> float:
    """True distance of the simulated base from the centre of ``cell``."""
    x, y = FLOOR.centre(cell)
    return math.hypot(rig.sim.x - x, rig.sim.y - y)


def test_move_east_reaches_the_next_cell(rig_factory: list[PtyRig]) -> None:
    rig = make(rig_factory, (1, 1), 0.0)
    events = rig.run(GridAction("0.0.0", (1, 1), (2, 1), "E", "E"))
    assert [e.kind for e in events] == ["started", "finished"]
    assert at(rig, (2, 1)) < POS_TOL
    assert abs(wrap_angle(rig.sim.theta)) < HEADING_TOL
    # 0.4 m at <= 0.2 m/s takes at least 2 s; the approach slows down but not forever.
    assert 2000 <= events[1].t_ms - events[0].t_ms <= 6000
    assert rig.commands[-1][1] == (0, 0)


def test_omni_move_turns_to_face_the_target_first(rig_factory: list[PtyRig]) -> None:
    rig = make(rig_factory, (2, 2), 0.0)  # facing E, told to go N (row - 1)
    events = rig.run(GridAction("0.0.1", (2, 2), (2, 1)))
    assert [e.kind for e in events] == ["started", "finished"]
    assert at(rig, (2, 1)) < POS_TOL
    assert abs(wrap_angle(rig.sim.theta - math.pi / 2)) < HEADING_TOL
    # It spun in place (radius 1) before driving straight or on wide arcs.
    radii = [cmd[1] for _, cmd in rig.commands if cmd != (0, 0)]
    assert radii[0] == 1 and radii[-1] != 1


@pytest.mark.parametrize(("start", "end", "theta0", "expected"), [
    ("E", "S", 0.0, -math.pi / 2), ("W", "E", math.pi, 0.0), ("N", "W", math.pi / 2, math.pi)])
def test_turn_in_place(rig_factory: list[PtyRig], start: str, end: str, theta0: float,
                       expected: float) -> None:
    rig = make(rig_factory, (1, 1), theta0)
    events = rig.run(GridAction("0.0.2", (1, 1), (1, 1), start, end))  # type: ignore[arg-type]
    assert [e.kind for e in events] == ["started", "finished"]
    assert abs(wrap_angle(rig.sim.theta - expected)) < HEADING_TOL
    assert at(rig, (1, 1)) < 0.005


def test_wait_lasts_its_duration_and_never_moves(rig_factory: list[PtyRig]) -> None:
    rig = make(rig_factory, (0, 0), 0.0)
    rig.tick()
    t0 = rig.now
    events = rig.run(GridAction("0.0.3", (0, 0), (0, 0), "E", "E", duration_ms=1000))
    # started on the first tick after the start (t0 + 20), finished on the first tick at which
    # 1000 ms have passed since t0.
    assert [(e.kind, e.t_ms) for e in events] == [("started", t0 + 20), ("finished", t0 + 1000)]
    assert all(cmd == (0, 0) for _, cmd in rig.commands)


def test_bumper_pauses_the_move_for_five_seconds(rig_factory: list[PtyRig]) -> None:
    rig = make(rig_factory, (0, 1), 0.0)
    rig.body.start(GridAction("0.0.4", (0, 1), (1, 1), "E", "E"), rig.now)
    for _ in range(25):  # 0.5 s of driving
        rig.tick()
    rig.sim.bumper = 0x02
    for _ in range(10):  # pressed for 200 ms
        rig.tick()
    last_contact = rig.now
    rig.sim.bumper = 0
    x_paused = rig.sim.x
    while rig.body.runner.busy:
        rig.tick()
        if rig.now < last_contact + 5000:
            assert rig.sim.command == (0, 0)
    kinds = [(e.kind, e.t_ms) for e in rig.events]
    assert [k for k, _ in kinds] == ["started", "blocked", "unblocked", "finished"]
    blocked_at, unblocked_at = kinds[1][1], kinds[2][1]
    assert blocked_at == last_contact - 180  # first tick that saw the contact
    assert unblocked_at == last_contact + 5000
    assert rig.sim.x > x_paused  # it went on after the pause
    assert at(rig, (1, 1)) < POS_TOL


def test_camera_fixes_correct_a_wrong_start_pose(rig_factory: list[PtyRig]) -> None:
    renderer = FloorRenderer(5, 4, 0.4, 0.12)
    error = (0.04, -0.03, math.radians(5))
    action = GridAction("0.0.5", (1, 2), (2, 2), "E", "E")
    blind = make(rig_factory, (1, 2), 0.0, pose_error=error)
    blind.run(action)
    seeing = make(rig_factory, (1, 2), 0.0, pose_error=error, renderer=renderer, frame_every=10)
    seeing.run(action)
    assert seeing.fixes >= 5
    assert at(seeing, (2, 2)) < POS_TOL
    assert at(blind, (2, 2)) > 0.03  # odometry alone keeps the start error


def test_a_path_of_moves_and_turns(rig_factory: list[PtyRig]) -> None:
    rig = make(rig_factory, (0, 0), 0.0)
    path = [((0, 0), (1, 0), "E", "E"), ((1, 0), (1, 0), "E", "S"), ((1, 0), (1, 1), "S", "S"),
            ((1, 1), (1, 1), "S", "S"), ((1, 1), (1, 1), "S", "W"), ((1, 1), (0, 1), "W", "W")]
    for i, (src, dst, h0, h1) in enumerate(path):
        events = rig.run(GridAction(f"0.0.{i}", src, dst, h0, h1))  # type: ignore[arg-type]
        assert [e.kind for e in events] == ["started", "finished"]
    assert at(rig, (0, 1)) < POS_TOL
    assert abs(wrap_angle(rig.sim.theta - math.pi)) < HEADING_TOL


@settings(max_examples=8, deadline=None)
@given(st.floats(-0.04, 0.04), st.floats(-0.04, 0.04), st.floats(-0.25, 0.25),
       st.sampled_from([((1, 1), (2, 1)), ((2, 1), (2, 2)), ((2, 2), (1, 2)), ((1, 2), (1, 1))]))
def test_moves_converge_from_an_offset_start(dx: float, dy: float, dtheta: float,
                                             move: tuple[tuple[int, int], tuple[int, int]]
                                             ) -> None:
    """The base starts up to 4 cm and 14 degrees off its cell centre and heading (and knows
    it); whatever the direction, it still ends on the target centre."""
    src, dst = move
    rig = PtyRig(FLOOR, src, HEADING_ANGLE[heading_of_step(src, dst)] + dtheta)
    try:
        rig.sim.x += dx
        rig.sim.y += dy
        rig.body.localiser.pose = Pose(rig.sim.x, rig.sim.y, rig.sim.theta)
        events = rig.run(GridAction("0.0.0", src, dst))
        assert [e.kind for e in events] == ["started", "finished"]
        assert at(rig, dst) < POS_TOL
    finally:
        rig.close()


def test_bad_actions_are_refused() -> None:
    runner = ActionRunner(FLOOR)
    with pytest.raises(ValueError, match="4-neighbour"):
        runner.start(GridAction("0.0.0", (0, 0), (1, 1)), 0.0)
    with pytest.raises(ValueError, match="duration"):
        runner.start(GridAction("0.0.0", (0, 0), (0, 0), duration_ms=0), 0.0)
    assert not runner.busy
    runner.start(GridAction("0.0.0", (0, 0), (0, 0)), 0.0)
    with pytest.raises(RuntimeError, match="busy"):
        runner.start(GridAction("0.0.1", (0, 0), (1, 0)), 0.0)


def test_body_remembers_the_pose_of_each_tick(rig_factory: list[PtyRig]) -> None:
    rig = make(rig_factory, (0, 0), 0.0)
    rig.body.start(GridAction("0.0.0", (0, 0), (1, 0), "E", "E"), rig.now)
    seen = []
    for _ in range(30):
        rig.tick()
        seen.append((rig.now, rig.body.pose))
    t, pose = seen[10]
    assert rig.body.pose_at(t) == pose and rig.body.pose_at(t + 19.0) == pose
    assert rig.body.pose_at(-1.0) == seen[0][1]  # older than the history: the oldest kept
    assert seen[29][1].x > seen[10][1].x  # it was moving, so the poses differ


def test_turning_move_drives_straight_without_spinning(rig_factory: list[PtyRig]) -> None:
    # facing E within 10 degrees: a turning move east drives off at once, never spins in place
    rig = make(rig_factory, (1, 2), math.radians(10))
    events = rig.run(GridAction("0.0.0", (1, 2), (2, 2), "E", "E"))
    assert [e.kind for e in events] == ["started", "finished"]
    assert at(rig, (2, 2)) < POS_TOL
    assert all(cmd[0] > 0 and cmd[1] != 1 for _, cmd in rig.commands if cmd != (0, 0))


def test_a_move_the_robot_does_not_face_is_refused(rig_factory: list[PtyRig]) -> None:
    rig = make(rig_factory, (2, 2), math.pi / 2)  # facing N
    with pytest.raises(ValueError, match=r"action 0\.0\.7: a move from \[2, 2\] facing E, but "
                                         r"the robot faces N \(heading 90 deg\): turn first"):
        rig.body.start(GridAction("0.0.7", (2, 2), (3, 2), "E", "E"), rig.now)
    assert not rig.body.runner.busy
    # a turning move must go forward along its unchanged heading
    for action, goes in [(GridAction("0.0.8", (2, 2), (3, 2), "N", "N"), "goes E"),
                         (GridAction("0.0.9", (2, 2), (2, 1), "N", "E"), "ends facing E")]:
        with pytest.raises(ValueError, match=goes):
            rig.body.start(action, rig.now)
    # after a 90-degree turn (odometry) it holds E and the move runs
    assert [e.kind for e in rig.run(GridAction("0.0.10", (2, 2), (2, 2), "N", "E"))] == [
        "started", "finished"]
    assert [e.kind for e in rig.run(GridAction("0.0.11", (2, 2), (3, 2), "E", "E"))] == [
        "started", "finished"]
    assert at(rig, (3, 2)) < POS_TOL


def test_camera_fixes_correct_the_heading_of_a_turn(rig_factory: list[PtyRig]) -> None:
    """A 90-degree turn by odometry alone keeps a wrong start heading; with OpenCV-rendered
    tag frames the AprilTag fixes correct it and the turn ends facing south."""
    renderer = FloorRenderer(5, 4, 0.4, 0.12)
    error = (0.0, 0.0, math.radians(8))
    turn = GridAction("0.0.12", (2, 1), (2, 1), "E", "S")
    blind = make(rig_factory, (2, 1), 0.0, pose_error=error)
    blind.run(turn)
    seeing = make(rig_factory, (2, 1), 0.0, pose_error=error, renderer=renderer, frame_every=10)
    seeing.run(turn)
    assert seeing.fixes >= 3
    assert abs(wrap_angle(seeing.sim.theta + math.pi / 2)) < HEADING_TOL
    assert abs(wrap_angle(blind.sim.theta + math.pi / 2)) > math.radians(6)
