"""Generators: connected maps, seeded determinism, valid random instances, shipped files."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from gateway.planning.connectivity import is_connected
from gateway.planning.distance import distance_table
from gateway.planning.generators import (
    random_instance,
    random_map,
    rooms_map,
    scenario_set,
    warehouse_map,
)
from gateway.planning.grid import Grid
from gateway.planning.instance import load_instance
from tests.planning.fleetgate_cli import call

SHIPPED = Path(__file__).resolve().parents[2] / "gateway" / "planning" / "maps"
LAB_RECIPE = ["warehouse", "lab", "--blocks-x", "3", "--blocks-y", "2", "--shelf-length", "2",
              "--shelf-depth", "2", "--aisle", "2", "--border", "2", "--scenarios", "5",
              "--agents", "20"]
WAREHOUSE_RECIPE = ["warehouse", "warehouse-small", "--blocks-x", "3", "--blocks-y", "3",
                    "--shelf-length", "5", "--shelf-depth", "2", "--aisle", "2", "--border",
                    "2", "--scenarios", "5", "--agents", "30"]
AISLES_RECIPE = ["warehouse", "warehouse-aisles", "--blocks-x", "4", "--blocks-y", "3",
                 "--shelf-length", "4", "--shelf-depth", "2", "--aisle", "1", "--border", "1",
                 "--scenarios", "5", "--agents", "20"]
FAST = settings(max_examples=40, deadline=None)


def _check_instance(grid: Grid, starts: tuple[tuple[int, int], ...],
                    goals: tuple[tuple[int, int], ...]) -> None:
    assert len(set(starts)) == len(starts)
    assert len(set(goals)) == len(goals)
    for s, g in zip(starts, goals, strict=True):
        assert grid.is_free(s) and grid.is_free(g) and s != g
        assert distance_table(grid, g)[grid.index(s)] > 0  # reachable, by BFS


@FAST
@given(st.integers(1, 20), st.integers(1, 20), st.floats(0, 0.6), st.integers(0, 2**32))
def test_random_map_is_connected_and_seeded(width: int, height: int, share: float,
                                            seed: int) -> None:
    grid = random_map(width, height, share, np.random.default_rng(seed))
    again = random_map(width, height, share, np.random.default_rng(seed))
    assert np.array_equal(grid.free, again.free)
    assert (grid.width, grid.height) == (width, height)
    if grid.free.any():
        assert is_connected(grid)
    # At least the asked share is blocked (more when cut-off pockets were filled).
    assert int((~grid.free).sum()) >= round(share * (width * height))  # as the generator


@FAST
@given(st.integers(1, 5), st.integers(1, 5), st.integers(1, 6), st.floats(0, 1),
       st.integers(0, 2**32))
def test_rooms_map_is_connected_and_seeded(rx: int, ry: int, size: int, extra: float,
                                           seed: int) -> None:
    grid = rooms_map(rx, ry, size, np.random.default_rng(seed), extra)
    assert np.array_equal(grid.free, rooms_map(rx, ry, size, np.random.default_rng(seed),
                                               extra).free)
    assert (grid.width, grid.height) == (rx * (size + 1) + 1, ry * (size + 1) + 1)
    assert is_connected(grid)
    # Rooms plus doors: a spanning tree needs rx * ry - 1 doors.
    assert int(grid.free.sum()) >= rx * ry * size * size + rx * ry - 1


@FAST
@given(st.integers(1, 4), st.integers(1, 4), st.integers(1, 6), st.integers(1, 3),
       st.integers(1, 3), st.integers(1, 3))
def test_warehouse_map_shape(bx: int, by: int, length: int, depth: int, aisle: int,
                             border: int) -> None:
    grid = warehouse_map(bx, by, length, depth, aisle, border)
    assert grid.width == 2 * border + bx * length + (bx - 1) * aisle
    assert grid.height == 2 * border + by * depth + (by - 1) * aisle
    assert int((~grid.free).sum()) == bx * by * length * depth
    assert is_connected(grid)


@FAST
@given(st.integers(2, 12), st.integers(2, 12), st.floats(0, 0.5), st.integers(1, 30),
       st.integers(0, 2**32))
def test_random_instance_is_valid_and_seeded(width: int, height: int, share: float,
                                             agents: int, seed: int) -> None:
    grid = random_map(width, height, share, np.random.default_rng(seed))
    free = int(grid.free.sum())
    if free < max(agents, 2):
        with pytest.raises(ValueError):
            random_instance(grid, agents, np.random.default_rng(seed))
        return
    inst = random_instance(grid, agents, np.random.default_rng(seed))
    assert inst.num_agents == agents
    _check_instance(grid, inst.starts, inst.goals)
    again = random_instance(grid, agents, np.random.default_rng(seed))
    assert (again.starts, again.goals) == (inst.starts, inst.goals)


def test_random_instance_keeps_goals_in_the_start_component() -> None:
    # Two 2-cell corridors cut apart by a wall column.
    grid = Grid(np.array([[True, True, False, True, True]]))
    for seed in range(20):
        inst = random_instance(grid, 4, np.random.default_rng(seed))
        _check_instance(grid, inst.starts, inst.goals)


def test_random_instance_fills_every_free_cell() -> None:
    # Two cells, two agents: the only valid instance swaps them, whatever the draw.
    grid = Grid(np.array([[True, True]]))
    for seed in range(10):
        inst = random_instance(grid, 2, np.random.default_rng(seed))
        assert inst.goals == (inst.starts[1], inst.starts[0])
    with pytest.raises(ValueError, match="no goal other than its start"):
        random_instance(Grid(np.array([[True]])), 1, np.random.default_rng(0))


def test_generators_reject_bad_parameters() -> None:
    rng = np.random.default_rng(0)
    with pytest.raises(ValueError, match="obstacle share"):
        random_map(4, 4, 1.0, rng)
    with pytest.raises(ValueError, match="at least 1"):
        warehouse_map(1, 1, 1, aisle=0)
    with pytest.raises(ValueError, match="need 3 free cells"):
        random_instance(Grid(np.array([[True, True]])), 3, rng)


def test_scenario_set_is_seeded_per_scenario() -> None:
    grid = warehouse_map(2, 2, 3)
    sets = scenario_set(grid, "w.map", 3, 5, seed=7)
    assert scenario_set(grid, "w.map", 3, 5, seed=7) == sets
    assert scenario_set(grid, "w.map", 2, 5, seed=7) == sets[:2]
    assert sets[0] != sets[1]
    for entries in sets:
        _check_instance(grid, tuple(e.start for e in entries), tuple(e.goal for e in entries))
        # optimal_length is the BFS distance here (4-connected)
        assert all(e.optimal_length == distance_table(grid, e.goal)[grid.index(e.start)]
                   for e in entries)


def test_lab_map_matches_its_description() -> None:
    lab = load_instance(SHIPPED / "lab.map", SHIPPED / "lab-random-1.scen", 15).grid
    assert (lab.width, lab.height, int(lab.free.sum())) == (14, 10, 116)


@pytest.mark.parametrize("recipe", [LAB_RECIPE, WAREHOUSE_RECIPE, AISLES_RECIPE],
                         ids=["lab", "warehouse", "aisles"])
def test_shipped_maps_are_what_maps_generate_writes(tmp_path: Path, recipe: list[str]) -> None:
    """The recipes in gateway/planning/maps/README.md give the shipped files byte for byte."""
    done = call("maps", "generate", *recipe, "--out", str(tmp_path))
    assert done.returncode == 0, done.stderr
    written = sorted(p.name for p in tmp_path.iterdir())
    assert len(written) == 6
    for name in written:
        assert (tmp_path / name).read_bytes() == (SHIPPED / name).read_bytes(), name


def test_maps_generate_random_and_rooms(tmp_path: Path) -> None:
    for kind in ("random", "rooms"):
        args = ["maps", "generate", kind, f"g-{kind}", "--out", str(tmp_path), "--seed", "3",
                "--scenarios", "2", "--agents", "10"]
        assert call(*args).returncode == 0
        inst = load_instance(tmp_path / f"g-{kind}.map", tmp_path / f"g-{kind}-random-2.scen")
        assert is_connected(inst.grid)
        _check_instance(inst.grid, inst.starts, inst.goals)
        again = call(*args)  # the files exist now: refused without --force, nothing changed
        assert again.returncode == 2
        assert "exists (use --force to overwrite)" in again.stderr


@pytest.mark.parametrize(("args", "reason"), [
    (["random", "x", "--obstacles", "1"], "obstacle share must be in [0, 1)"),
    (["warehouse", "x", "--aisle", "0"], "every warehouse dimension must be at least 1"),
    (["random", "x", "--width", "2", "--height", "2", "--obstacles", "0", "--scenarios", "1",
      "--agents", "5"], "5 agents need 5 free cells"),
])
def test_maps_generate_bad_parameters(tmp_path: Path, args: list[str], reason: str) -> None:
    done = call("maps", "generate", *args, "--out", str(tmp_path))
    assert done.returncode == 2
    assert reason in done.stderr
    assert list(tmp_path.iterdir()) == []
