"""Large neighbourhood search (LNS) over a planned window of the guided ``turning`` planner.

:class:`~gateway.planning.pibt.WindowedPIBT` decides one timestep at a time, each robot its
best next state by the tables; a robot that loses a cell to a robot of higher priority waits,
or turns towards a cell that another robot then takes. After such a window, :func:`refine`
takes small groups of neighbouring robots out of it, plans each again, one after the other,
by the cheapest path through the window that avoids everyone else's (an exhaustive search over
its few timesteps and the ``turning`` actions), and keeps the new paths only if the group's
cost falls (in the manner of MAPF-LNS, Li et al., IJCAI 2021, as the LoRR 2023 winner's WPPL
refines its windows, arXiv 2404.16162).

A path's cost (:func:`path_cost`) is what the planner weighs its moves by: each action's own
cost (a wait :data:`~gateway.planning.guidance.MOVE`, a turn the space's ``turn``, a forward
move its lane's cost), while the robot has a goal left, plus the table of its next goal at the
window's end, less :data:`REACH` for each goal reached. The rules every path keeps are the
planner's: no two robots on one cell at a timestep, nobody enters a cell another robot held at
the previous timestep (1-robust), no cell of ``avoid`` is entered, and robot r waits through
its first ``hold[r]`` timesteps. So a refined window is as valid as the window it refines, and
its cost is never higher (:func:`window_cost`).

The search is bounded by iterations, not by time: a call's result depends on its inputs and
its seed only.
"""

from __future__ import annotations

import random
from collections.abc import Sequence
from typing import Protocol

KEYS = 64
"""Goals a robot may have, and one more (a search's key packs a state and its goals reached)."""
REACH = 1 << 20
"""What reaching a goal takes off a path's cost: more than any table entry, so a path that
reaches more goals is always the cheaper."""
RADIUS = 2
"""A group is a robot and the robots standing within this many cells of it (both axes) at the
window's start."""
GROUP = 6
"""The most robots of one group."""


class GuidedSpace(Protocol):
    """What :func:`refine` reads of a :class:`~gateway.planning.pibt.StateSpace` (exact,
    guided tables over the ``turning`` states)."""

    cell_of: list[int]

    def distances(self, goal: int) -> Sequence[int]:
        """The table of ``goal`` (by state)."""
        ...  # pragma: no cover

    def moves(self, state: int) -> tuple[tuple[int, int, int], ...]:
        """``(state, cell, own cost)`` of each action from ``state``, the wait first."""
        ...  # pragma: no cover


def action_cost(space: GuidedSpace, s: int, s2: int) -> int:
    """The own cost of the action from state ``s`` to ``s2`` (one of its :meth:`moves`)."""
    for s3, _, own in space.moves(s):
        if s3 == s2:
            return own
    raise ValueError(f"no action leads from state {s} to {s2}")


def path_cost(space: GuidedSpace, path: Sequence[int], goals: Sequence[int]) -> int:
    """The cost of a robot's ``path`` (its states at the window's timesteps) towards its
    ``goals`` in order (see the module's docstring; a robot without a goal left: 1 for each
    action but a wait, so it stays unless it makes room)."""
    cell_of = space.cell_of
    k, cost = 0, 0
    while k < len(goals) and goals[k] == cell_of[path[0]]:
        k += 1
        cost -= REACH
    for t in range(1, len(path)):
        s, s2 = path[t - 1], path[t]
        if k < len(goals):
            cost += action_cost(space, s, s2)
        elif s2 != s:
            cost += 1
        c = cell_of[s2]
        while k < len(goals) and goals[k] == c:
            k += 1
            cost -= REACH
    if k < len(goals):
        cost += space.distances(goals[k])[path[-1]]
    return cost


def window_cost(space: GuidedSpace, states: Sequence[Sequence[int]],
                goals: Sequence[Sequence[int]]) -> int:
    """The summed :func:`path_cost` of every robot of a window (``states[t][r]``)."""
    return sum(path_cost(space, [row[r] for row in states], goals[r])
               for r in range(len(goals)))


def best_path(space: GuidedSpace, start: int, goals: Sequence[int], occ: list[list[int]],
              hold: int, avoid: set[int]) -> list[int] | None:
    """The cheapest path (:func:`path_cost`) from ``start`` over the ``len(occ) - 1``
    timesteps of the window that keeps the rules against the robots of ``occ`` (``occ[t]``:
    cell -> robot or -1 at timestep t, this robot not among them), waiting through the first
    ``hold`` timesteps and entering no cell of ``avoid``; None if there is none. A search over
    the states and goals reached at each timestep (at most four actions a state)."""
    cell_of, moves = space.cell_of, space.moves
    n_goals = len(goals)
    if n_goals >= KEYS:
        raise ValueError(f"at most {KEYS - 1} goals a robot, not {n_goals}")
    k0, base = 0, 0
    while k0 < n_goals and goals[k0] == cell_of[start]:
        k0 += 1
        base -= REACH
    # a layer: key (state * KEYS + goals reached) -> (cost so far, the previous key)
    layers: list[dict[int, tuple[int, int]]] = [{start * KEYS + k0: (base, -1)}]
    for t in range(1, len(occ)):
        here, before = occ[t], occ[t - 1]
        layer: dict[int, tuple[int, int]] = {}
        for key, (cost, _) in layers[-1].items():
            s, k = divmod(key, KEYS)
            c = cell_of[s]
            if here[c] >= 0:  # someone enters (or stays on) the cell this robot holds
                continue
            for s2, c2, own in moves(s)[:1] if t <= hold else moves(s):
                if c2 != c and (here[c2] >= 0 or before[c2] >= 0 or c2 in avoid):
                    continue
                k2 = k
                if k2 < n_goals:
                    cost2 = cost + own
                    while k2 < n_goals and goals[k2] == c2:
                        k2 += 1
                        cost2 -= REACH
                else:
                    cost2 = cost + (s2 != s)
                key2 = s2 * KEYS + k2
                old = layer.get(key2)
                if old is None or cost2 < old[0]:
                    layer[key2] = (cost2, key)
        if not layer:
            return None
        layers.append(layer)
    best_key, best = -1, 0
    for key, (cost, _) in layers[-1].items():
        s, k = divmod(key, KEYS)
        total = cost + (space.distances(goals[k])[s] if k < n_goals else 0)
        if best_key < 0 or total < best:
            best_key, best = key, total
    path: list[int] = []
    node = best_key
    for layer in reversed(layers):
        path.append(node // KEYS)
        node = layer[node][1]
    path.reverse()
    return path


def refine(space: GuidedSpace, width: int, states: list[list[int]],
           goals: Sequence[Sequence[int]], hold: Sequence[int] | None, avoid: Sequence[int],
           iterations: int, rng: random.Random,
           priority: Sequence[int] | None = None) -> int:
    """Improve the window ``states`` (``states[t][r]``, changed in place; the grid ``width``
    cells wide) by ``iterations`` rounds of LNS; returns how much its :func:`window_cost`
    fell (0 or more). Each round takes a robot that waits or turns in the window while it has
    a goal (at random), with its neighbours (:data:`RADIUS`, :data:`GROUP`), plans them again
    one after the other by :func:`best_path` (by ``priority``, highest first, if given, e.g.
    the planner's timesteps since each robot's last goal; ties and else in a random order),
    and keeps their new paths if their summed cost is lower."""
    n = len(goals)
    steps = len(states) - 1
    if n == 0 or steps == 0 or iterations <= 0:
        return 0
    cell_of = space.cell_of
    size = len(cell_of) // 4  # four headings a cell: the turning states
    paths = [[row[r] for row in states] for r in range(n)]
    occ = [[-1] * size for _ in range(steps + 1)]
    for r, path in enumerate(paths):
        for t, s in enumerate(path):
            occ[t][cell_of[s]] = r
    costs = [path_cost(space, paths[r], goals[r]) for r in range(n)]
    avoided = set(avoid)
    holds = hold if hold is not None else [0] * n
    gained = 0
    slow = [r for r in range(n) if goals[r] and _stalls(paths[r], holds[r], cell_of)]
    for _ in range(iterations if slow else 0):
        seed = slow[int(rng.random() * len(slow))]
        group = _neighbours(seed, paths, occ[0], cell_of, width, size)
        rng.shuffle(group)
        if priority is not None:
            group.sort(key=lambda r: -priority[r])
        old = sum(costs[r] for r in group)
        for r in group:
            for t, s in enumerate(paths[r]):
                occ[t][cell_of[s]] = -1
        new_paths: dict[int, list[int]] = {}
        for r in group:
            p = best_path(space, paths[r][0], goals[r], occ, holds[r], avoided)
            if p is None:
                break
            new_paths[r] = p
            for t, s in enumerate(p):
                occ[t][cell_of[s]] = r
        new_costs = ({r: path_cost(space, p, goals[r]) for r, p in new_paths.items()}
                     if len(new_paths) == len(group) else {})
        keep = bool(new_costs) and sum(new_costs.values()) < old
        for found in new_paths.values():
            for t, s in enumerate(found):
                occ[t][cell_of[s]] = -1
        for r in group:
            if keep:
                paths[r] = new_paths[r]
                costs[r] = new_costs[r]
            for t, s in enumerate(paths[r]):
                occ[t][cell_of[s]] = r
        if keep:
            gained += old - sum(new_costs.values())
    for t, row in enumerate(states):
        for r in range(n):
            row[r] = paths[r][t]
    return gained


def _stalls(path: Sequence[int], hold: int, cell_of: Sequence[int]) -> bool:
    """Whether a path (of states; ``cell_of``: state -> cell) waits or turns after its
    ``hold`` timesteps."""
    return any(cell_of[path[t]] == cell_of[path[t - 1]] for t in range(hold + 1, len(path)))


def _neighbours(seed: int, paths: Sequence[Sequence[int]], first: Sequence[int],
                cell_of: Sequence[int], width: int, size: int) -> list[int]:
    """``seed`` and the robots on cells within :data:`RADIUS` of its start cell at the
    window's start (``first``: cell -> robot), nearest first, at most :data:`GROUP`."""
    c = cell_of[paths[seed][0]]
    x, y = c % width, c // width
    found = []
    for dy in range(-RADIUS, RADIUS + 1):
        for dx in range(-RADIUS, RADIUS + 1):
            nx, ny = x + dx, y + dy
            if 0 <= nx < width and 0 <= ny * width + nx < size and ny >= 0:
                o = first[ny * width + nx]
                if o >= 0 and o != seed:
                    found.append((abs(dx) + abs(dy), o))
    found.sort()
    return [seed] + [o for _, o in found[: GROUP - 1]]
