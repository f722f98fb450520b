"""Traffic guidance for the ``turning`` planner: soft one-way lanes and the tables they weigh.

A guidance gives every ``turning`` state ``4 * cell + heading`` the cost of its forward move;
a turn and a wait cost :data:`MOVE`. :func:`crisscross` is the hand-made guidance of the
guidance-graph literature (Zhang et al., "Guidance Graph Optimization for Lifelong MAPF",
IJCAI 2024; the LoRR 2023 winner's WPPL, arXiv 2404.16162, optimises one instead): even rows
run east, odd rows west, even columns south, odd columns north, and a move against its lane
costs ``penalty`` more. Robots still go anywhere (the lanes are soft), but opposite flows
mostly take different lanes, so fewer robots meet head-on, where the 1-robust rule and the
cost of turning round hurt most. :func:`crowded` adds the crowd of the moment: a move into a
cell costs half a move more for each robot standing around it, and tables are searched again as
they age (:meth:`~gateway.planning.pibt.StateSpace.guide`): on the LoRR room map, clusters of
robots had waited 40-70 ticks on both sides of one-cell doors while other doors of the same
wall stood empty. :func:`guided_tables` are the exact costs to a goal under a guidance (a
Dijkstra search backwards over the states with a bucket queue, compiled with numba as
:mod:`gateway.planning.bfs_kernel` is). Where tables over the states do not fit (10,000 robots
on LoRR's warehouse_large), :func:`corridor_lanes` set the one-cell aisles of a warehouse one
way in turns, and :func:`guided_cell_tables` are the costs over the cells, turns free.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import numpy.typing as npt
from numba import njit

from gateway.planning.connectivity import component_labels
from gateway.planning.distance import turning_predecessor_table
from gateway.planning.grid import Grid
from gateway.planning.motion import HEADING_MOVES

MOVE = 2
"""Cost of one action (a move along its lane, a turn, a wait) in a guided table: an even unit,
so half a move can be a penalty."""


def crisscross(grid: Grid, penalty: int) -> npt.NDArray[np.int32]:
    """The forward-move cost of each state ``4 * cell + heading`` (headings east, south,
    west, north): :data:`MOVE`, plus ``penalty`` against the lane (even rows east, odd rows
    west, even columns south, odd columns north)."""
    if penalty < 0:
        raise ValueError(f"a lane penalty must be at least 0, not {penalty}")
    cells = np.arange(grid.size)
    x, y = cells % grid.width, cells // grid.width
    along = np.stack([y % 2 == 0, x % 2 == 0, y % 2 == 1, x % 2 == 1], axis=1)
    return np.where(along, MOVE, MOVE + penalty).astype(np.int32).ravel()


@njit(cache=True, nogil=True)
def _bucket_groups(pred: npt.NDArray[np.int32], cost: npt.NDArray[np.int32],
                   sources: npt.NDArray[np.int64], bounds: npt.NDArray[np.int64],
                   out: npt.NDArray[np.int32]) -> None:
    """Fill ``out[k]`` (all -1) with the cheapest costs to the sources
    ``sources[bounds[k]:bounds[k + 1]]`` over a graph given backwards: ``pred[v, j]`` is a
    node one step before v (``pred.shape[0] - 1``: none), ``cost[v, j]`` (at least 1) that
    step's cost (:func:`guided_tables`: turning states; :func:`guided_cell_tables`: cells).

    Dijkstra with a bucket queue (Dial's), one bucket per cost modulo the dearest step plus
    one; a stale entry, reached cheaper since, is skipped. (A two-FIFO variant for two
    distinct costs was no faster: 14-20 ms against 14-18 ms for 64 tables of random-400,
    158-232 ms against 189-262 ms on the city map; removed.)"""
    n = pred.shape[0] - 1
    buckets = int(cost.max()) + 1
    cap = pred.shape[1] * n + 8
    node = np.empty(cap, dtype=np.int64)
    link = np.empty(cap, dtype=np.int64)
    for k in range(bounds.shape[0] - 1):
        row = out[k]
        first = np.full(buckets, -1, dtype=np.int64)
        used = 0
        pending = 0
        for i in range(bounds[k], bounds[k + 1]):
            s = sources[i]
            row[s] = 0
            node[used] = s
            link[used] = first[0]
            first[0] = used
            used += 1
            pending += 1
        d = 0
        while pending > 0:
            b = d % buckets
            e = first[b]
            first[b] = -1
            while e >= 0:
                v = node[e]
                e = link[e]
                pending -= 1
                if row[v] != d:
                    continue
                for j in range(pred.shape[1]):
                    u = pred[v, j]
                    if u >= n:
                        continue
                    nd = d + cost[v, j]
                    if row[u] < 0 or nd < row[u]:
                        row[u] = nd
                        node[used] = u
                        link[used] = first[nd % buckets]
                        first[nd % buckets] = used
                        used += 1
                        pending += 1
            d += 1


def guided_tables(grid: Grid, goals: Sequence[int], forward: npt.NDArray[np.int32],
                  turn: int = MOVE) -> npt.NDArray[np.int32]:
    """``out[k, 4 * cell + heading]``: the cheapest cost from that state to standing on cell
    ``goals[k]`` (flat ids, any heading) when a turn costs ``turn`` (at least :data:`MOVE`)
    and the forward move of state u ``forward[u]`` (:func:`crisscross`, or :func:`crowded`:
    any costs of at least :data:`MOVE`); -1 if unreachable. With every forward cost and the
    turn :data:`MOVE` it is :data:`MOVE` times the exact timesteps."""
    if forward.shape != (4 * grid.size,):
        raise ValueError(f"a guidance of {forward.shape[0]} states for a map of "
                         f"{4 * grid.size}")
    if turn < MOVE:
        raise ValueError(f"a turn must cost at least {MOVE}, not {turn}")
    free = grid.free.ravel()
    for g in goals:
        if not 0 <= g < grid.size or not free[g]:
            raise ValueError(f"goal {g} is not a free cell of {grid!r}")
    out = np.full((len(goals), 4 * grid.size), -1, dtype=np.int32)
    if goals:
        flat = np.array([4 * g + h for g in goals for h in range(4)], dtype=np.int64)
        bounds = np.arange(0, 4 * len(goals) + 1, 4, dtype=np.int64)
        pred = turning_predecessor_table(grid)  # columns 0 and 1 turn, 2 moves forward
        cost = np.full(pred.shape, turn, dtype=np.int32)
        cost[:, 2] = np.append(forward, np.int32(MOVE)).astype(np.int32)[pred[:, 2]]
        _bucket_groups(pred, cost, flat, bounds, out)
    return out


def _corridors(grid: Grid) -> tuple[npt.NDArray[np.bool_], npt.NDArray[np.bool_]]:
    """The free cells walled north and south (in an east-west corridor) and those walled west
    and east (north-south), as ``(height, width)`` masks; off the map is a wall."""
    free = np.pad(grid.free, 1, constant_values=False)
    mid = free[1:-1, 1:-1]
    return (mid & ~free[:-2, 1:-1] & ~free[2:, 1:-1], mid & ~free[1:-1, :-2] & ~free[1:-1, 2:])


def corridor_share(grid: Grid) -> float:
    """The share of the free cells of ``grid`` in one-cell corridors (:func:`corridor_lanes`):
    0.63 on LoRR's warehouse_large, 0.009 on the game map brc202d."""
    ns, we = _corridors(grid)
    return float((ns | we).sum()) / max(1, int(grid.free.sum()))


def corridor_lanes(grid: Grid, penalty: int) -> npt.NDArray[np.int32]:
    """The forward-move cost of each state ``4 * cell + heading`` (as :func:`crisscross`) on a
    map of one-cell corridors (a warehouse's aisles between shelves): the rows that hold a
    stretch of corridor running east-west (free cells walled north and south) take turns, in
    order from the north, at running east and west, and the columns of north-south corridors
    (walled east and west) at running south and north; a move against its row's or column's
    lane costs ``penalty`` more. Rows and columns without such a corridor have no lane. On
    LoRR's warehouse_large the corridors lie every third row and every fourth column, which
    :func:`crisscross`'s parity lanes would set all one way."""
    if penalty < 0:
        raise ValueError(f"a lane penalty must be at least 0, not {penalty}")
    walled_ns, walled_we = _corridors(grid)
    rows, cols = np.asarray(walled_ns.any(axis=1)), np.asarray(walled_we.any(axis=0))
    h, w = grid.height, grid.width
    has_row, has_col = np.repeat(rows, w), np.tile(cols, h)  # per cell, row by row
    east = np.repeat(np.cumsum(rows) % 2 == 1, w)  # odd: the first, third, ... corridor row
    south = np.tile(np.cumsum(cols) % 2 == 1, h)
    out = np.full((grid.size, 4), MOVE, dtype=np.int32)  # headings east, south, west, north
    out[has_row & ~east, 0] += penalty
    out[has_row & east, 2] += penalty
    out[has_col & ~south, 1] += penalty
    out[has_col & south, 3] += penalty
    return out.ravel()


def guided_cell_tables(grid: Grid, goals: Sequence[int], forward: npt.NDArray[np.int32]
                       ) -> npt.NDArray[np.int32]:
    """``out[k, cell]``: the cheapest cost from ``cell`` to ``goals[k]`` when the move from a
    cell u in heading d costs ``forward[4 * u + d]`` (a lane guidance, :func:`corridor_lanes`)
    and turns cost nothing: a table per cell, not per state, for maps where those do not fit;
    -1 if unreachable."""
    free = grid.free.ravel()
    for g in goals:
        if not 0 <= g < grid.size or not free[g]:
            raise ValueError(f"goal {g} is not a free cell of {grid!r}")
    out = np.full((len(goals), grid.size), -1, dtype=np.int32)
    if goals:
        n = grid.size
        # the cell behind each cell in each heading: the one whose forward move enters it
        behind = _ahead(grid).reshape(n, 4)[:, [2, 3, 0, 1]]
        behind[~free] = n
        behind[~np.append(free, False)[behind]] = n  # a blocked cell is behind nobody
        pred = np.vstack([behind, np.full((1, 4), n)]).astype(np.int32)
        cost = np.append(forward, np.full(4, MOVE)).astype(np.int32)[
            np.minimum(4 * pred.astype(np.int64) + np.arange(4), 4 * n)]
        _bucket_groups(pred, cost, np.asarray(goals, dtype=np.int64),
                       np.arange(len(goals) + 1, dtype=np.int64), out)
    return out


CROWD_RADIUS = 1
"""A cell's crowd counts the robots within this many cells of it in x and y (its 3 x 3 box)."""
CROWD_WEIGHT = MOVE // 2
"""What each robot of a cell's crowd adds to a move into it: half a move. With the default
lanes (penalty 3), 600 ticks, delay seeds 0-5: random 3010 -> 3150 tasks (every seed above
every seed without), room 797 -> 805, maze 254 -> 254 (seeds 0-2), city 254 (seed 0); a
whole move: random 2992, room 805; half a move over the 5 x 5 box: random 1529 (seeds 0-2,
against 1500), room 790."""
CROWD_AGE = 3
"""Guided planning calls after which a table is searched again with the crowd of the moment
(:meth:`~gateway.planning.pibt.StateSpace.guide`)."""
CROWD_BUDGET = 1_000_000
"""States a call searches again at most (61 tables of a 64 x 64 map, 3 of the 256 x 256 city
map), so a large map's tables are refreshed a few at a time and a call stays short."""


def crowd(grid: Grid, cells: Sequence[int], radius: int = CROWD_RADIUS
          ) -> npt.NDArray[np.int32]:
    """Per cell (flat id), the robots standing on ``cells`` within ``radius`` cells of it in x
    and y (a box sum of the robots' occupancy)."""
    h, w = grid.height, grid.width
    occupied = np.zeros(grid.size, dtype=np.int32)
    occupied[np.asarray(cells, dtype=np.int64)] = 1
    sums = np.pad(occupied.reshape(h, w), radius + 1).cumsum(0).cumsum(1)
    k = 2 * radius + 1
    box = sums[k:k + h, k:k + w] - sums[:h, k:k + w] - sums[k:k + h, :w] + sums[:h, :w]
    return np.ascontiguousarray(box.ravel(), dtype=np.int32)


def crowded(grid: Grid, forward: npt.NDArray[np.int32], cells: Sequence[int]
            ) -> npt.NDArray[np.int32]:
    """Forward-move costs ``forward`` (:func:`crisscross`) plus :data:`CROWD_WEIGHT` for each
    robot around the cell each move enters (:func:`crowd`, robots on ``cells``): in the manner of
    the LoRR winners' traffic-flow guidance against congestion, so robots bound the same way
    spread over doors and corridors instead of queueing at one."""
    around = np.append(crowd(grid, cells), np.int32(0))  # the sentinel: no cell ahead
    return forward + CROWD_WEIGHT * around[_ahead(grid)]


def _ahead(grid: Grid) -> npt.NDArray[np.int64]:
    """The cell in front of each state ``4 * cell + heading`` (``grid.size`` off the map)."""
    cells = np.arange(grid.size)
    x, y = cells % grid.width, cells // grid.width
    out = np.full((grid.size, 4), grid.size, dtype=np.int64)
    for h, (dx, dy) in enumerate(HEADING_MOVES):
        nx, ny = x + dx, y + dy
        inside = (nx >= 0) & (nx < grid.width) & (ny >= 0) & (ny < grid.height)
        out[inside, h] = (ny * grid.width + nx)[inside]
    return out.ravel()


DOOR_ROOM = 16
"""Cells a region needs for its doors to be made one way (:func:`one_way_doors`): a pocket of a
few cells behind a gap among obstacles is no room (random-64-64-10 has two such; the shared
maze and city maps none either way)."""


def door_cells(grid: Grid) -> list[tuple[int, int]]:
    """The one-cell doors of ``grid`` as ``(cell, axis)``, in cell order: a free cell whose
    two neighbours on one axis are blocked (or off the map) and whose two on the other axis are
    free (axis 0: walls west and east, the passage runs north-south; 1: walls north and
    south)."""
    free = np.pad(grid.free, 1, constant_values=False)
    mid = free[1:-1, 1:-1]
    north, south = free[:-2, 1:-1], free[2:, 1:-1]
    west, east = free[1:-1, :-2], free[1:-1, 2:]
    axis0 = mid & ~west & ~east & north & south
    axis1 = mid & ~north & ~south & west & east
    cells = np.flatnonzero(axis0 | axis1)
    return [(c, 0 if axis0.flat[c] else 1) for c in cells.tolist()]


def regions(grid: Grid, cut: Sequence[int]) -> npt.NDArray[np.int64]:
    """Each cell's region (0, 1, ..., in row-major order of their first cell): the connected
    parts (4-neighbours, :func:`~gateway.planning.connectivity.component_labels`) of the free
    cells of ``grid`` without the cells ``cut``; -1 on a blocked or cut cell."""
    free = grid.free.copy()
    free.ravel()[np.asarray(cut, dtype=np.int64)] = False
    return component_labels(Grid(free)).ravel().astype(np.int64) - 1


def one_way_doors(grid: Grid, penalty: int) -> npt.NDArray[np.int32]:
    """What one-way doors add to each state's forward-move cost (``4 * cell + heading``, as
    :func:`crisscross`): where two regions (:func:`regions` of the map cut at its
    :func:`door_cells`, :data:`DOOR_ROOM` cells or more each) have two or more doors between
    them, those doors take turns, in cell order, at running from the region of the lower number
    to the other and back, and a move into a door against its direction, or on through it,
    costs ``penalty`` more (soft: a robot may still go against it). On the LoRR room map,
    robots bound both ways had queued on both sides of its doors."""
    if penalty < 0:
        raise ValueError(f"a door penalty must be at least 0, not {penalty}")
    out = np.zeros(4 * grid.size, dtype=np.int32)
    if not penalty:
        return out
    w = grid.width
    doors = door_cells(grid)
    label = regions(grid, [c for c, _ in doors])
    sizes = np.bincount(label[label >= 0], minlength=1)
    pairs: dict[tuple[int, int], list[tuple[int, int, bool]]] = {}
    for c, axis in doors:
        step = w if axis == 0 else 1
        a, b = int(label[c - step]), int(label[c + step])
        if a != b and min(a, b) >= 0 and min(sizes[a], sizes[b]) >= DOOR_ROOM:
            pairs.setdefault((min(a, b), max(a, b)), []).append((c, step, a < b))
    for members in pairs.values():
        if len(members) < 2:
            continue
        for i, (c, step, low_first) in enumerate(members):
            forth = low_first == (i % 2 == 0)  # the door runs from c - step to c + step
            # against it: heading north (3) or west (2) when it runs south or east, from c + step
            against = (3 if step == w else 2) if forth else (1 if step == w else 0)
            back = c + step if forth else c - step
            out[4 * back + against] += penalty
            out[4 * c + against] += penalty
    return out
