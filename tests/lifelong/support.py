"""Small generated lifelong instances for the tests."""

from __future__ import annotations

import numpy as np

from gateway.planning.generators import random_map
from gateway.planning.grid import Grid
from gateway.planning.lorr import DelayConfig, LorrProblem


def small_problem(seed: int, robots: int = 12, size: int = 12, counter: int = 2,
                  p_delay: float = 0.05, obstacles: float = 0.15) -> LorrProblem:
    """A random map with random starts and 1-3-errand tasks, delays on."""
    rng = np.random.default_rng(seed)
    grid: Grid = random_map(size, size, obstacles, rng)
    free = np.flatnonzero(grid.free.ravel())
    starts = tuple(int(c) for c in rng.choice(free, size=robots, replace=False))
    tasks = tuple(tuple(int(c) for c in rng.choice(free, size=int(rng.integers(1, 4))))
                  for _ in range(4 * robots))
    delay = DelayConfig(seed=seed, min_delay=1, max_delay=6, event_model="bernoulli",
                        p_delay=p_delay)
    return LorrProblem(grid=grid, starts=starts, tasks=tasks, num_tasks_reveal=1.5,
                       agent_counter=counter, delay=delay, name=f"small-{seed}")
