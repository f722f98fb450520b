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
    scenario_entries,
    warehouse_map,
)
from gateway.planning.grid import Grid
from gateway.planning.instance import load_instance
from gateway.planning.movingai import format_map, format_scen

SHIPPED = Path(__file__).resolve().parents[2] / "gateway" / "planning" / "maps"
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
        assert is_connected(grid.free)
    # At least the asked share is blocked (more when cut-off pockets were filled).
    assert int((~grid.free).sum()) >= round(share * width * height)


@FAST
@given(st.integers(1, 5), st.integers(1, 5), st.integers(1, 6), st.floats(0, 1),
       st.integers(0, 2**32))
def test_rooms_map_is_connected_and_seeded(rx: int, ry: int, size: int, extra: float,
                                           seed: int) -> None:
    grid = rooms_map(rx, ry, size, np.random.default_rng(seed), extra)
    assert np.array_equal(grid.free, rooms_map(rx, ry, size, np.random.default_rng(seed),
                                               extra).free)
    assert (grid.width, grid.height) == (rx * (size + 1) + 1, ry * (size + 1) + 1)
    assert is_connected(grid.free)
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
    assert is_connected(grid.free)


@FAST
@given(st.integers(2, 12), st.integers(2, 12), st.floats(0, 0.5), st.integers(1, 30),
       st.integers(0, 2**32))
def test_random_instance_is_valid_and_seeded(width: int, height: int, share: float,
                                             agents: int, seed: int) -> None:
    grid = random_map(width, height, share, np.random.default_rng(seed))
    free = int(grid.free.sum())
    if free < agents + 1:
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


def test_generators_reject_bad_parameters() -> None:
    rng = np.random.default_rng(0)
    with pytest.raises(ValueError, match="obstacle share"):
        random_map(4, 4, 1.0, rng)
    with pytest.raises(ValueError, match="at least 1"):
        warehouse_map(1, 1, 1, aisle=0)
    with pytest.raises(ValueError, match="need 3 free cells"):
        random_instance(Grid(np.array([[True, True]])), 3, rng)


@pytest.mark.parametrize(("name", "grid", "agents"), [
    ("lab", warehouse_map(3, 2, 2, 2, aisle=2, border=2, name="lab.map"), 20),
    ("warehouse-small", warehouse_map(3, 3, 5, 2, aisle=2, border=2,
                                      name="warehouse-small.map"), 30),
])
def test_shipped_maps_are_what_the_generators_make(name: str, grid: Grid, agents: int) -> None:
    """The recipe in gateway/planning/maps/README.md, byte for byte."""
    assert (SHIPPED / f"{name}.map").read_text() == format_map(grid)
    for seed in range(1, 6):
        inst = random_instance(grid, agents, np.random.default_rng(seed))
        scen = SHIPPED / f"{name}-random-{seed}.scen"
        assert scen.read_text() == format_scen(scenario_entries(inst, f"{name}.map"))
        loaded = load_instance(SHIPPED / f"{name}.map", scen)
        assert (loaded.starts, loaded.goals) == (inst.starts, inst.goals)


def test_lab_map_matches_its_description() -> None:
    lab = load_instance(SHIPPED / "lab.map", SHIPPED / "lab-random-1.scen", 15).grid
    assert (lab.width, lab.height, int(lab.free.sum())) == (14, 10, 116)
