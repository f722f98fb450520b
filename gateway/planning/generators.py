"""Map and instance generators; all randomness comes from a caller's ``numpy.random.Generator``.

Every generated map is 4-connected (one component of free cells), so any two free cells are
joined by a path.
"""

from __future__ import annotations

import numpy as np

from gateway.planning.connectivity import component_labels, largest_component
from gateway.planning.distance import distance_table
from gateway.planning.grid import Grid
from gateway.planning.instance import Instance
from gateway.planning.movingai import ScenEntry


def random_map(width: int, height: int, obstacle_share: float, rng: np.random.Generator,
               name: str = "") -> Grid:
    """A ``width`` x ``height`` map with ``round(obstacle_share * width * height)`` obstacles
    placed uniformly at random; free cells cut off from the largest component are then blocked
    too, so the map is connected and its obstacle share may exceed the one asked for."""
    if width < 1 or height < 1:
        raise ValueError(f"map size must be positive, got {width}x{height}")
    if not 0 <= obstacle_share < 1:
        raise ValueError(f"obstacle share must be in [0, 1), got {obstacle_share}")
    cells = width * height
    blocked = rng.choice(cells, size=round(obstacle_share * cells), replace=False)
    free = np.ones(cells, dtype=bool)
    free[blocked] = False
    return Grid(largest_component(Grid(free.reshape(height, width))), name=name)


def _room_tree_doors(rooms_x: int, rooms_y: int, extra_doors: float,
                     rng: np.random.Generator) -> list[tuple[tuple[int, int], tuple[int, int]]]:
    """Pairs of adjacent rooms joined by a door: a random spanning tree (randomised
    depth-first search), plus every other adjacent pair with probability ``extra_doors``."""
    start = (0, 0)
    seen = {start}
    stack = [start]
    doors: list[tuple[tuple[int, int], tuple[int, int]]] = []
    while stack:
        rx, ry = stack[-1]
        fresh = [(rx + dx, ry + dy) for dx, dy in ((1, 0), (-1, 0), (0, 1), (0, -1))
                 if 0 <= rx + dx < rooms_x and 0 <= ry + dy < rooms_y
                 and (rx + dx, ry + dy) not in seen]
        if not fresh:
            stack.pop()
            continue
        nxt = fresh[int(rng.integers(len(fresh)))]
        seen.add(nxt)
        doors.append(((rx, ry), nxt))
        stack.append(nxt)
    tree = {frozenset(d) for d in doors}
    for rx in range(rooms_x):
        for ry in range(rooms_y):
            for other in ((rx + 1, ry), (rx, ry + 1)):
                if (other[0] < rooms_x and other[1] < rooms_y
                        and frozenset(((rx, ry), other)) not in tree
                        and rng.random() < extra_doors):
                    doors.append(((rx, ry), other))
    return doors


def rooms_map(rooms_x: int, rooms_y: int, room_size: int, rng: np.random.Generator,
              extra_doors: float = 0.3, name: str = "") -> Grid:
    """A grid of ``room_size`` x ``room_size`` rooms behind 1-cell walls (with an outer wall).

    Rooms are joined by 1-cell doors at random places along their shared wall: a random
    spanning tree of doors keeps every room reachable, and each further pair of adjacent
    rooms gets a door with probability ``extra_doors``.
    """
    if rooms_x < 1 or rooms_y < 1 or room_size < 1:
        raise ValueError("rooms_x, rooms_y and room_size must be positive")
    step = room_size + 1
    free = np.zeros((rooms_y * step + 1, rooms_x * step + 1), dtype=bool)
    for rx in range(rooms_x):
        for ry in range(rooms_y):
            free[1 + ry * step: ry * step + step, 1 + rx * step: rx * step + step] = True
    for (ax, ay), (bx, by) in _room_tree_doors(rooms_x, rooms_y, extra_doors, rng):
        offset = 1 + int(rng.integers(room_size))
        if ax != bx:  # a vertical wall between horizontal neighbours
            free[min(ay, by) * step + offset, max(ax, bx) * step] = True
        else:
            free[max(ay, by) * step, min(ax, bx) * step + offset] = True
    return Grid(free, name=name)


def warehouse_map(blocks_x: int, blocks_y: int, shelf_length: int, shelf_depth: int = 1,
                  aisle: int = 1, border: int = 1, name: str = "") -> Grid:
    """Shelf blocks of ``shelf_length`` x ``shelf_depth`` cells in ``blocks_y`` rows of
    ``blocks_x``, separated by ``aisle`` free cells and surrounded by ``border`` free cells.

    Width is ``2 * border + blocks_x * shelf_length + (blocks_x - 1) * aisle`` and height
    ``2 * border + blocks_y * shelf_depth + (blocks_y - 1) * aisle``. Every shelf is walled by
    aisles, so the map is connected.
    """
    if min(blocks_x, blocks_y, shelf_length, shelf_depth, aisle, border) < 1:
        raise ValueError("every warehouse dimension must be at least 1")
    width = 2 * border + blocks_x * shelf_length + (blocks_x - 1) * aisle
    height = 2 * border + blocks_y * shelf_depth + (blocks_y - 1) * aisle
    free = np.ones((height, width), dtype=bool)
    for bx in range(blocks_x):
        for by in range(blocks_y):
            x0 = border + bx * (shelf_length + aisle)
            y0 = border + by * (shelf_depth + aisle)
            free[y0: y0 + shelf_depth, x0: x0 + shelf_length] = False
    return Grid(free, name=name)


def random_instance(grid: Grid, agents: int, rng: np.random.Generator,
                    name: str = "") -> Instance:
    """``agents`` agents with distinct starts and distinct goals, drawn uniformly at random;
    each goal lies in its start's component and differs from it.

    Raises ``ValueError`` when the map has too few free cells for that (an agent alone in a
    one-cell component).
    """
    if agents < 1:
        raise ValueError(f"the number of agents must be at least 1, got {agents}")
    labels = component_labels(grid).ravel()
    free_ids = np.flatnonzero(labels)
    if free_ids.size < agents:
        raise ValueError(f"{agents} agents need {agents} free cells, {grid!r} has "
                         f"{free_ids.size}")
    starts = rng.choice(free_ids, size=agents, replace=False)
    goal_taken = np.zeros(labels.size, dtype=bool)
    goals: list[int] = []
    start_list = [int(s) for s in starts]
    for k, s in enumerate(start_list):
        options = np.flatnonzero((labels == labels[s]) & ~goal_taken)
        options = options[options != s]
        if options.size:
            g = int(rng.choice(options))
        else:
            # Only s itself is left in its component: an earlier agent there takes s as its
            # goal and hands its own goal over.
            j = next((j for j in range(k) if labels[start_list[j]] == labels[s]), None)
            if j is None:
                raise ValueError(f"no goal other than its start for the agent at "
                                 f"{grid.cell(s)}")
            g, goals[j] = goals[j], s
            goal_taken[s] = True
        goal_taken[g] = True
        goals.append(g)
    return Instance(grid, tuple(grid.cell(int(s)) for s in starts),
                    tuple(grid.cell(g) for g in goals), name)


def scenario_entries(instance: Instance, map_name: str, bucket: int = 0) -> list[ScenEntry]:
    """The ``.scen`` lines of an instance; ``optimal_length`` is the 4-connected distance
    (MovingAI's own files give the octile distance instead)."""
    out: list[ScenEntry] = []
    for i, (start, goal) in enumerate(zip(instance.starts, instance.goals, strict=True)):
        dist = distance_table(instance.grid, goal)
        out.append(ScenEntry(start=start, goal=goal, line=i + 2, bucket=bucket,
                             map_name=map_name, width=instance.grid.width,
                             height=instance.grid.height,
                             optimal_length=float(dist[instance.grid.index(start)])))
    return out



def scenario_set(grid: Grid, map_name: str, count: int, agents: int,
                 seed: int) -> list[list[ScenEntry]]:
    """``count`` scenarios of ``agents`` random agents each; scenario i (1-based) draws from
    ``numpy.random.default_rng([seed, i])``, so each is reproducible on its own."""
    return [scenario_entries(random_instance(grid, agents, np.random.default_rng([seed, i])),
                             map_name) for i in range(1, count + 1)]
