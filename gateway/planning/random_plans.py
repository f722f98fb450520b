"""Random valid 1-robust plans (property tests, benchmarks), built step by step without a planner.

At every timestep the robots, in a random order, either wait or move to a free 4-neighbour
that no other robot stood on at the previous step and no robot has claimed for this step;
that is exactly the 1-robust rule of DESIGN section 2, so any such walk is a valid plan.
"""

from __future__ import annotations

import random

import numpy as np

from gateway.planning.grid import Cell, Grid
from gateway.planning.plan import Plan


def open_grid(width: int, height: int) -> Grid:
    """A ``width`` x ``height`` map without obstacles."""
    return Grid(np.ones((height, width), dtype=bool), name=f"open-{width}x{height}")


def random_walks(grid: Grid, robots: int, steps: int, rng: random.Random,
                 move_share: float = 0.7) -> list[list[Cell]]:
    """``robots`` random walks of ``steps`` timesteps (``steps + 1`` cells each), 1-robust."""
    cells = list(grid.free_cells())
    positions: list[Cell] = rng.sample(cells, robots)
    paths = [[p] for p in positions]
    for _ in range(steps):
        before = set(positions)
        claimed: set[Cell] = set()
        order = list(range(robots))
        rng.shuffle(order)
        for k in order:
            options = [c for c in grid.neighbours(positions[k])
                       if c not in before and c not in claimed]
            if options and rng.random() < move_share:
                positions[k] = rng.choice(options)
            claimed.add(positions[k])
        for k in range(robots):
            paths[k].append(positions[k])
    return paths


def random_plan(grid: Grid, robots: int, steps: int, rng: random.Random,
                move_share: float = 0.7) -> Plan:
    """A random 1-robust plan of ``robots`` walkers over ``steps`` timesteps
    (:func:`random_walks`, trailing goal waits trimmed)."""
    return Plan.of(random_walks(grid, robots, steps, rng, move_share))
