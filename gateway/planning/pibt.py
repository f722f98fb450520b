"""A windowed, 1-robust PIBT planner for lifelong operation (pure, scales to thousands).

Each call plans ``steps`` timesteps ahead for the whole fleet, one timestep at a time, in
the manner of PIBT (Okumura et al., AIJ 2022): robots decide in priority order (a robot on
its last goal first, then time since its last goal, then a random tie-break), each takes its
best successor state by the exact distance to its goal, and a robot that wants a cell held
by a robot that has not decided yet asks that robot to move away first (priority
inheritance). The difference from PIBT is the 1-robust rule (DESIGN section 2): a robot
never enters a cell that another robot held at the previous timestep, so an asked robot
clears the cell during this timestep and the asker enters at the next. ``omni`` (states are
cells) and ``turning`` (states are ``cell * 4 + heading``, actions forward, clockwise,
counter-clockwise, wait) are both supported.

Guarantees: every returned step is free of vertex conflicts and 1-robust (waiting in place is
always possible, and nobody else may enter a held cell), so :class:`~gateway.execution.
live_adg.LiveADG` accepts it and its execution is collision-free under any delays. Each
timestep costs O(robots x actions) plus the pushes. Like PIBT it is not complete: in rare
cyclic jams robots may wait until priorities rotate. Distances are the exact tables of
:mod:`gateway.planning.distance` (cells, or ``turning`` states), one per goal cell, cached
within a memory budget.
"""

from __future__ import annotations

import random
from array import array
from collections import OrderedDict
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from gateway.planning.bfs_kernel import pack_mod3
from gateway.planning.distance import cell_distance_rows, free_index, turning_distance_tables
from gateway.planning.grid import Grid
from gateway.planning.guidance import (
    CROWD_AGE,
    CROWD_BUDGET,
    MOVE,
    crowded,
    guided_cell_tables,
    guided_tables,
)
from gateway.planning.lns import refine
from gateway.planning.motion import HEADING_MOVES

UNREACHABLE = 32000
"""Distance of a state that cannot reach the goal (tables are int16)."""
COMPACT_BASE = 1 << 10
"""What :meth:`StateSpace.costs` adds to the moves relative to the own cell (costs stay
positive, as the moves of a robot not on its goal are)."""
MAX_PUSH_DEPTH = 64
"""Longest chain of robots asked to move away within one timestep."""


def exact_fits(grid: Grid, robots: int, budget_bytes: int) -> bool:
    """Whether two exact tables over the ``turning`` states per robot (of ``robots``, 32 at
    least) fit ``budget_bytes``: :class:`StateSpace`'s default for ``exact``."""
    return 2 * max(robots, 32) * 8 * grid.size <= budget_bytes


def compact_needed(grid: Grid, robots: int, budget_bytes: int) -> bool:
    """Whether a table over the free cells (2 bytes a cell) per robot of ``robots`` would
    not fit ``budget_bytes``: :class:`StateSpace`'s tables are then :attr:`~StateSpace.compact`
    (when not exact)."""
    return 2 * robots * int(grid.free.sum()) > budget_bytes


class StateSpace:
    """The planner's state graph on a grid: successors per state, and distance tables.

    ``omni``: state = cell id, successors = free 4-neighbours and the cell itself (wait).
    ``turning``: state = ``cell * 4 + heading``; successors = forward (if free), clockwise,
    counter-clockwise, wait. ``cell_of[s]`` is the cell a state stands on.

    Tables (:func:`goal_tables`) are cached in an LRU of ``budget_bytes``. Under ``omni`` they
    are exact moves over the free cells (2 bytes a free cell). Under ``turning`` they are exact
    over the states (8 bytes a cell) when ``exact``, by default when two tables per robot of
    ``robots`` fit the budget; otherwise one table per goal serves the four headings: the moves
    over the free cells, a lower bound of the turning cost (a quarter of the memory or less, for
    10,000 robots on the competition's large maps). :attr:`options` name the table entry each
    move is weighed by accordingly. Tables over the free cells are :attr:`compact` (2 bits a
    cell: the moves modulo 3, :func:`compact_rows`) when one of 2 bytes a cell per robot would
    not fit the budget (10,000 robots on a million-cell map); :meth:`costs` weighs a robot's
    moves alike from either kind. A ``guidance`` (forward-move costs per state, :mod:`gateway.
    planning.guidance`) weighs exact tables, or tables over the free cells (turns free in the
    table: :func:`~gateway.planning.guidance.guided_cell_tables`), not compact ones.
    """

    def __init__(self, grid: Grid, turning: bool, budget_bytes: int = 1 << 30,
                 robots: int = 0, exact: bool | None = None,
                 guidance: npt.NDArray[np.int32] | None = None, turn: int = MOVE) -> None:
        self.grid = grid
        self.turning = turning
        n = grid.size
        if exact is None:
            exact = exact_fits(grid, robots, budget_bytes)
        self.exact = turning and exact
        """Whether tables are over the states (else over the free cells)."""
        if guidance is not None and not turning:
            raise ValueError("a guidance needs the turning model")
        self.guidance = guidance
        """Each state's forward-move cost (:mod:`gateway.planning.guidance`; None: every
        action costs one): tables and :meth:`costs` are then in its units."""
        self.turn = turn
        """What a turn costs under a :attr:`guidance` (tables and :meth:`costs`)."""
        self._forward: list[int] = guidance.tolist() if guidance is not None else []
        self._heading_to = {dx + dy * grid.width: h for h, (dx, dy) in enumerate(HEADING_MOVES)}
        self._lanes = guidance
        self._calls = 0  # guided calls so far (:meth:`guide`)
        self._searched: dict[int, int] = {}  # goal -> the guided call its table is from
        self.index = free_index(grid)
        """Each cell's position in a table over the free cells (-1: obstacle)."""
        self.n_states = 4 * n if turning else n
        self.cell_of: list[int] = ([s >> 2 for s in range(self.n_states)] if turning
                                   else list(range(n)))
        self.options = _Options(grid, turning, self.exact, self.index)
        self._moves: dict[int, tuple[tuple[int, int, int], ...]] = {}
        self._cache: OrderedDict[int, array[int]] = OrderedDict()
        entries = self.n_states if self.exact else int(grid.free.sum())
        self.compact = not self.exact and compact_needed(grid, robots, budget_bytes)
        if self.compact and guidance is not None:
            raise ValueError("a guidance needs tables of costs, not compact ones")
        """Whether tables hold the moves modulo 3 (:func:`compact_rows`), not the moves."""
        size = (entries + 3) // 4 if self.compact else 2 * entries
        self._capacity = max(16, budget_bytes // size)

    def state(self, cell: int, heading: int = 0) -> int:
        """The state of a robot on ``cell`` (facing ``heading`` under ``turning``)."""
        return 4 * cell + heading if self.turning else cell

    def heading_of(self, state: int) -> int:
        """The heading of a state (0 under ``omni``)."""
        return state & 3 if self.turning else 0

    @property
    def capacity(self) -> int:
        """How many tables the cache keeps (its memory budget over a table's size)."""
        return self._capacity

    def distances(self, goal: int) -> array[int]:
        """Actions to standing on cell ``goal`` (any heading), from every state if
        :attr:`exact`, else from every free cell (at :attr:`index`); cached."""
        table = self._cache.get(goal)
        if table is not None:
            self._cache.move_to_end(goal)
            return table
        self.prefetch([goal])
        return self._cache[goal]

    def cached(self, goal: int) -> bool:
        """Whether the table of ``goal`` is cached."""
        return goal in self._cache

    def missing(self, goals: Iterable[int]) -> list[int]:
        """The goals of ``goals`` without a cached table, sorted, each once."""
        cache = self._cache
        return sorted({g for g in goals if g not in cache})

    def prefetch(self, goals: Sequence[int]) -> None:
        """Compute the missing tables of ``goals`` together (one batched search)."""
        missing = self.missing(goals)
        if missing:
            self.offer(goal_tables(self.grid, self.exact, missing, self.compact,
                                   self.guidance, self.turn))
            if self._calls:
                self._searched.update(dict.fromkeys(missing, self._calls))

    def guide(self, cells: Sequence[int], goals: Iterable[int]) -> None:
        """A guided planning call with robots on ``cells`` (needs a :attr:`guidance`): the
        forward costs from now on are the lanes' plus the crowd of the moment
        (:func:`~gateway.planning.guidance.crowded`), and the oldest cached tables of ``goals``
        searched :data:`~gateway.planning.guidance.CROWD_AGE` guided calls ago or more are
        dropped (searched again when asked for), as many as :data:`~gateway.planning.
        guidance.CROWD_BUDGET` states allow."""
        if self._lanes is None:
            raise ValueError("crowd guidance needs a guidance (lanes, or none: crisscross 0)")
        self._calls += 1
        self.guidance = crowded(self.grid, self._lanes, cells)  # the tables' (:meth:`costs`
        # weighs a robot's own next move by the lanes alone: by the crowd, a move into a
        # crowded cell, its own robot counted, would cost more than a wait, and robots froze)
        searched, cache = self._searched, self._cache
        stale = sorted((searched.get(g, 0), g) for g in set(goals)
                       if g in cache and self._calls - searched.get(g, 0) >= CROWD_AGE)
        for _, g in stale[: CROWD_BUDGET // self.n_states]:
            del cache[g]

    def costs(self, table: array[int], opts: Sequence[tuple[int, int, int, int]]) -> list[int]:
        """The cost of each move of :attr:`options` ``opts`` (the wait first) towards the goal
        of ``table``: its table entry plus its turns. From a :attr:`compact` table, the moves
        relative to the robot's own cell (neighbours differ by exactly one move on a grid), plus
        :data:`COMPACT_BASE`: the same order and differences as the moves themselves. Under a
        :attr:`guidance`, each move's own cost (the wait and a turn :data:`~gateway.planning.
        guidance.MOVE`, a turn :attr:`turn`, a move its lane's cost) plus the table entry after
        it."""
        if self.guidance is not None and self.exact:
            forward, turn = self._forward, self.turn
            own = opts[0][1]
            c = own >> 2
            return [table[es] + (MOVE if es == own else turn * turns + forward[4 * c + (es & 3)])
                    for _, es, turns, _ in opts]
        if self.guidance is not None:  # tables over the cells: a move's heading from its cell
            forward, turn, c = self._forward, self.turn, opts[0][0]
            heading = self._heading_to
            return [table[opts[0][1]] + MOVE] + [
                table[es] + turn * turns + forward[4 * c + heading[nxt - c]]
                for nxt, es, turns, _ in opts[1:]]
        if not self.compact:
            return [table[es] + turns for _, es, turns, _ in opts]
        own = (table[opts[0][1] >> 2] >> ((opts[0][1] & 3) << 1)) & 3
        out = []
        for _, es, turns, _ in opts:
            code = (table[es >> 2] >> ((es & 3) << 1)) & 3
            out.append(UNREACHABLE + turns if code == 3
                       else COMPACT_BASE + (code - own + 1) % 3 - 1 + turns)
        return out

    def moves(self, state: int) -> tuple[tuple[int, int, int], ...]:
        """Each action from ``state`` under a :attr:`guidance` as ``(resulting state, its
        cell, the action's own cost)``, each resulting state once, the wait first: a wait
        :data:`~gateway.planning.guidance.MOVE`, a turn :attr:`turn`, a forward move its
        lane's cost (what :meth:`costs` weighs a move by, :mod:`gateway.planning.lns`)."""
        out = self._moves.get(state)
        if out is None:
            cell_of, seen = self.cell_of, []
            for _, _, _, rs in self.options[state]:
                if rs not in seen:
                    seen.append(rs)
            out = self._moves[state] = tuple(
                (rs, cell_of[rs], MOVE if rs == state else self.turn
                 if cell_of[rs] == cell_of[state] else self._forward[state]) for rs in seen)
        return out

    def offer(self, tables: Mapping[int, array[int]]) -> None:
        """Cache tables computed elsewhere (:func:`goal_tables` of this grid and kind, e.g.
        in another process); a table already cached is kept."""
        cache = self._cache
        for g, table in tables.items():
            if g not in cache:
                cache[g] = table
        while len(cache) > self._capacity:
            cache.popitem(last=False)


class _Options:
    """``options[s]``: the moves of state s, built when first asked for (a million-cell map
    has four million states; robots visit few), as ``(cell, table entry weighing it, turns,
    resulting state)`` per neighbour cell and the own cell (a wait). Under ``turning`` a robot
    that does not face the chosen cell turns towards it this timestep (and stays)."""

    def __init__(self, grid: Grid, turning: bool, exact: bool,
                 index: npt.NDArray[np.int32]) -> None:
        self.grid = grid
        self.turning = turning
        self.exact = exact
        self.index = index.tolist()
        self._built: dict[int, tuple[tuple[int, int, int, int], ...]] = {}

    def __getitem__(self, s: int) -> tuple[tuple[int, int, int, int], ...]:
        opts = self._built.get(s)
        if opts is None:
            opts = self._built[s] = self._build(s)
        return opts

    def _build(self, s: int) -> tuple[tuple[int, int, int, int], ...]:
        grid, index = self.grid, self.index
        if not self.turning:
            if index[s] < 0:
                return ()
            return ((s, index[s], 0, s),
                    *((v, index[v], 0, v) for v in grid.neighbour_ids(s)))
        c, h = s >> 2, s & 3
        if index[c] < 0:
            return ()
        w, n = grid.width, grid.size
        x = c % w
        opts = [(c, s if self.exact else index[c], 0, s)]
        for d, delta in enumerate((1, w, -1, -w)):  # the headings' order
            nxt = c + delta
            if (not 0 <= nxt < n or index[nxt] < 0
                    or (d == 0 and x == w - 1) or (d == 2 and x == 0)):
                continue
            entry = 4 * nxt + d if self.exact else index[nxt]
            turns = (d - h) % 4
            if turns == 0:
                opts.append((nxt, entry, 0, 4 * nxt + h))
            else:
                step = 1 if turns in (1, 2) else 3
                opts.append((nxt, entry, min(turns, 4 - turns), 4 * c + (h + step) % 4))
        return tuple(opts)


def goal_tables(grid: Grid, exact: bool, goals: Sequence[int], compact: bool = False,
                guidance: npt.NDArray[np.int32] | None = None, turn: int = MOVE
                ) -> dict[int, array[int]]:
    """The distance table of each goal cell (:meth:`StateSpace.distances`: int16, capped at
    :data:`UNREACHABLE`): over the ``turning`` states if ``exact`` (the costs under
    ``guidance`` if given, a turn costing ``turn``: :func:`~gateway.planning.guidance.
    guided_tables`), else over the
    free cells (exact moves, a lower bound of the turning cost, or the costs under ``guidance``
    with turns free: :func:`~gateway.planning.guidance.guided_cell_tables`), searched in batches;
    ``compact`` (not with ``exact``): :func:`compact_rows` of those over the free cells."""
    out: dict[int, array[int]] = {}
    for i in range(0, len(goals), 32):
        chunk = goals[i : i + 32]
        if guidance is not None and exact:
            found = guided_tables(grid, chunk, guidance, turn)
        elif guidance is not None:
            found = guided_cell_tables(grid, chunk, guidance)[:, grid.free.ravel()]
        else:
            found = (turning_distance_tables(grid, [grid.cell(g) for g in chunk]) if exact
                     else cell_distance_rows(grid, chunk))
        if compact:
            out.update(zip(chunk, compact_rows(found), strict=True))
            continue
        found[found < 0] = UNREACHABLE  # in place, row by row below: no batch-sized copies
        np.minimum(found, UNREACHABLE, out=found)  # (a million-cell map's batch is 75 MB)
        for g, row in zip(chunk, found, strict=True):
            out[g] = array("h", row.astype(np.int16).tobytes())
    return out


def compact_rows(found: npt.NDArray[np.int32]) -> list[array[int]]:
    """Each row of moves (-1: unreachable) as 2 bits an entry, four entries a byte from the
    lowest bits up: the moves modulo 3, or 3 where unreachable (a sixteenth of int32 rows)."""
    packed = np.zeros((found.shape[0], (found.shape[1] + 3) // 4), dtype=np.uint8)
    pack_mod3(found, packed)
    return [array("B", row.tobytes()) for row in packed]


@dataclass
class Window:
    """A planned window: ``states[j][r]`` for steps 0..steps, and for each robot the steps at
    which it reached each of its goals, in order (``reached[r][i]`` for ``goals[r][i]``)."""

    states: list[list[int]]
    reached: list[list[int]]


class WindowedPIBT:
    """1-robust PIBT over a :class:`StateSpace`, keeping priorities between calls."""

    def __init__(self, space: StateSpace, n_robots: int, seed: int = 0,
                 guided: bool = False, turn_to_leaving: bool = False, lns: int = 0) -> None:
        self.space = space
        self.lns = lns if space.guidance is not None and space.exact else 0
        """Rounds of :func:`~gateway.planning.lns.refine` over each window (guided exact
        tables only; 0: none)."""
        self.guided = guided
        """Whether each call guides the tables by the crowd (:meth:`StateSpace.guide`; the
        space needs a guidance): a call then depends on the calls before it, not only on its
        inputs."""
        self.turn_to_leaving = turn_to_leaving
        """Whether a robot may turn in place towards a cell whose robot leaves it at that
        timestep (:meth:`_enter_held`; else it never turns towards a held cell)."""
        self.n = n_robots
        self.seed = seed
        self.rng = random.Random(seed)
        self.elapsed = [0] * n_robots
        self.tie = [self.rng.random() for _ in range(n_robots)]
        n_cells = space.grid.size
        self._occupant = [-1] * n_cells
        self._reserved = [0] * n_cells
        self._planned = [0] * n_robots
        self._stamp = 0
        self._avoid = [0] * n_cells
        self._call = 0

    def start_from(self, elapsed: Sequence[int], key: int) -> None:
        """Make the next :meth:`plan` start from the priorities ``elapsed`` (timesteps since
        each robot last reached a goal) and the random stream of ``key``, not from what the
        calls before left: that call is then a function of its inputs (a restarted planner
        given the same priorities and key plans the same window)."""
        if len(elapsed) != self.n:
            raise ValueError(f"priorities for {len(elapsed)} robots, the planner has {self.n}")
        self.elapsed = list(elapsed)
        self.rng.seed(f"{self.seed}/{key}")

    def plan(self, states: Sequence[int], goals: Sequence[Sequence[int]], steps: int,
             hold: Sequence[int] | None = None, avoid: Sequence[int] = ()) -> Window:
        """Plan ``steps`` timesteps from ``states``; ``goals[r]`` are robot r's next goal cells
        in order (empty: no goal; it waits unless asked to move away). Robot r waits through
        the first ``hold[r]`` steps (e.g. the committed actions it still has to do before it
        stands on its start state, so its new moves come when it can make them); the others
        plan around it, and enter no cell of ``avoid`` (e.g. cells a delayed robot will
        still drive through)."""
        space, n = self.space, self.n
        cell_of = space.cell_of
        cur = list(states)
        if len({cell_of[s] for s in cur}) != n:
            raise ValueError("two robots stand on the same cell")
        if self.guided:
            space.guide([cell_of[s] for s in cur], [g[0] for g in goals if g])
        space.prefetch([g[0] for g in goals if g])
        elapsed = list(self.elapsed)
        progress = [0] * n
        reached: list[list[int]] = [[] for _ in range(n)]
        for r in range(n):
            self._arrive(r, cur[r], goals[r], progress, reached, 0)
        out = [cur]
        occupant = self._occupant
        self._call += 1
        for c in avoid:
            self._avoid[c] = self._call
        for r, s in enumerate(cur):
            occupant[cell_of[s]] = r
        for step in range(1, steps + 1):
            space.prefetch([g[progress[r]] for r, g in enumerate(goals) if progress[r] < len(g)])
            tables = [space.distances(g[progress[r]]) if progress[r] < len(g) else None
                      for r, g in enumerate(goals)]
            last = [len(g) - progress[r] == 1 for r, g in enumerate(goals)]
            nxt = self._step(cur, tables, hold, step, last)
            for s in cur:
                occupant[cell_of[s]] = -1
            for r, s in enumerate(nxt):
                occupant[cell_of[s]] = r
                self._arrive(r, s, goals[r], progress, reached, step)
            out.append(nxt)
            cur = nxt
        for s in cur:
            occupant[cell_of[s]] = -1
        if self.lns:
            rng = random.Random(f"{self.seed}/lns/{self._call}")
            if refine(space, space.grid.width, out, goals, hold, avoid, self.lns, rng,
                      elapsed):
                self.elapsed = elapsed  # the refined window's arrivals and priorities
                progress = [0] * n
                reached = [[] for _ in range(n)]
                for step, row in enumerate(out):
                    for r in range(n):
                        self._arrive(r, row[r], goals[r], progress, reached, step)
        return Window(out, reached)

    def _arrive(self, r: int, state: int, goals: Sequence[int], progress: list[int],
                reached: list[list[int]], step: int) -> None:
        cell = self.space.cell_of[state]
        k = progress[r]
        hit = False
        while k < len(goals) and goals[k] == cell:
            reached[r].append(step)
            k += 1
            hit = True
        progress[r] = k
        if hit:
            self.elapsed[r] = 0
        elif k < len(goals):
            self.elapsed[r] += 1

    def _step(self, cur: list[int], tables: list[array[int] | None],
              hold: Sequence[int] | None, step: int, last: list[bool]) -> list[int]:
        """One timestep. Robots on their last goal (``last``: about to finish a task, which a
        robot still heading for its first errand may yet hand to another) decide first: on the
        shared LoRR problems (600 ticks, room 8 delay seeds, random 6) room 121.8 -> 124.3
        tasks, random 451.7 -> 465.3 (every seed 461 or more, 432-467 before), maze 76.5 ->
        77.4."""
        self._stamp += 1
        stamp = self._stamp
        n = self.n
        nxt = list(cur)
        elapsed, tie = self.elapsed, self.tie
        order = sorted(range(n), key=lambda r: (tables[r] is None, not last[r], -elapsed[r],
                                                -tie[r]))
        planned = self._planned
        if hold is not None:
            for r in range(n):
                if hold[r] >= step:
                    planned[r] = stamp
        for r in order:
            if planned[r] != stamp:
                self._decide(r, -1, cur, nxt, tables, 0)
        return nxt

    def _candidates(self, s: int, table: array[int] | None, pushed: bool
                    ) -> list[tuple[int, int]]:
        """The moves of a robot in state ``s`` towards the goal of ``table`` as ``(cell,
        resulting state)``, best first: by cost, then waiting (preferred on ties, the last
        resort if ``pushed``: asked to leave), a free cell before a held one, fewer turns, a
        random tie-break."""
        space, occupant = self.space, self._occupant
        c = space.cell_of[s]
        rng = self.rng.random
        keyed = []
        opts = space.options[s]  # the wait first
        costs = space.costs(table, opts) if table is not None else [0] * len(opts)
        if space.turning and not space.exact and len(costs) > 1 and costs[0]:
            # the cells' bound does not see that a robot must turn before it can move: waiting
            # costs a timestep more than the best move (Bellman), as the exact tables say
            costs[0] = max(costs[0], 1 + min(costs[1:]))
        for (c2, _, turns, rs), cost in zip(opts, costs, strict=True):
            if c2 == c:
                keyed.append((cost + (UNREACHABLE if pushed else 0), 0, 0, rng(), c2, rs))
            else:
                keyed.append((cost, 1 if occupant[c2] < 0 else 2, turns, rng(), c2, rs))
        keyed.sort()
        return [(c2, rs) for _, _, _, _, c2, rs in keyed]

    def _enter_held(self, r: int, o: int, pusher: int, rs: int, cur: list[int],
                    nxt: list[int], tables: list[array[int] | None], depth: int) -> bool:
        """Whether robot r may take state ``rs`` towards the cell robot ``o`` holds now: it
        asks ``o`` to clear the cell; r may not enter it (1-robust: at the next timestep it
        may), and it may turn towards it in place only if :attr:`turn_to_leaving` and ``o``
        leaves it. With that, robots whose best move is a turn towards a leaving robot's cell
        (2.2% of the robot-timesteps of random-400 under the 2024 rules) turn instead of
        waiting: random-400 under the 2024 rules 509 -> 525 tasks (3 planner seeds); under the
        2026 rules maze, random and city unchanged, room with its one-way doors 144.7 -> 138.0
        (delay seeds 0-2), so the LoRR simulator turns it on under the 2024 rules only."""
        if o != pusher and self._planned[o] != self._stamp and depth < MAX_PUSH_DEPTH:
            self._decide(o, r, cur, nxt, tables, depth + 1)
        cell_of = self.space.cell_of
        return (self.turn_to_leaving and cell_of[rs] == cell_of[cur[r]]
                and cell_of[nxt[o]] != cell_of[cur[o]])

    def _decide(self, r: int, pusher: int, cur: list[int], nxt: list[int],
                tables: list[array[int] | None], depth: int) -> None:
        """Choose robot r's next state (``pusher`` >= 0: that robot wants r's cell)."""
        stamp = self._stamp
        self._planned[r] = stamp
        space = self.space
        cell_of, occupant, reserved = space.cell_of, self._occupant, self._reserved
        avoid, call = self._avoid, self._call
        s = cur[r]
        c = cell_of[s]
        for c2, rs in self._candidates(s, tables[r], pusher >= 0):
            if c2 == c:
                nxt[r] = rs
                reserved[c] = stamp
                return
            if reserved[c2] == stamp or avoid[c2] == call:
                continue
            o = occupant[c2]
            if o >= 0 and not self._enter_held(r, o, pusher, rs, cur, nxt, tables, depth):
                continue
            nxt[r] = rs
            reserved[cell_of[rs]] = stamp  # the cell, or the own cell for a turn towards it
            return
        nxt[r] = s  # unreachable: waiting in place is always a candidate
        reserved[c] = stamp
