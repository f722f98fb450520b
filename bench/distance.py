"""Distance tables: the compiled search against the numpy frontier search it replaced.

Builds ``--goals`` turning tables (4 states a cell) and as many cell tables on a generated
warehouse (``--blocks``; the default is about the size of LoRR's warehouse_large, 38,000 free
cells), or on a LoRR/MovingAI map given with ``--map``, with both searches in this process
(CPU seconds; the tables must be equal). Prints one result line with the speed-up.

    .venv/bin/python bench/distance.py --goals 64
"""

from __future__ import annotations

import fleetgate.userio.script  # noqa: F401 (first: Ctrl-C while importing is one line)

# isort: split

import time
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np
import numpy.typing as npt

from fleetgate.userio.exits import CommandParser, run_main
from gateway.planning.distance import (
    _multi_bfs,
    neighbour_table,
    turning_predecessor_table,
)
from gateway.planning.generators import warehouse_map
from gateway.planning.movingai import parse_map

Search = Callable[[npt.NDArray[np.int32], Sequence[Sequence[int]]], npt.NDArray[np.int32]]


def numpy_bfs(table: npt.NDArray[np.int32],
              sources: Sequence[Sequence[int]]) -> npt.NDArray[np.int32]:
    """The numpy frontier search fleetgate used before (the baseline): all groups expand
    together, one numpy gather per level over the union of one copy of the graph per group."""
    n = table.shape[0] - 1
    block = n + 1
    k = len(sources)
    dist = np.full(k * block, -1, dtype=np.int32)
    offsets = np.arange(k, dtype=np.int64) * block
    dist[offsets + n] = 0
    frontier = np.unique(np.concatenate([np.asarray(src, dtype=np.int64) + offsets[i]
                                         for i, src in enumerate(sources)]))
    dist[frontier] = 0
    stamp = np.zeros(k * block, dtype=np.int64)
    d = 0
    while frontier.size:
        d += 1
        base = frontier - frontier % block
        cand = (table[frontier - base] + base[:, None]).ravel()
        cand = cand[dist[cand] < 0]
        order = np.arange(cand.size)
        stamp[cand] = order
        cand = cand[stamp[cand] == order]
        dist[cand] = d
        frontier = cand
    return dist.reshape(k, block)[:, :n].copy()


def timed(search: Search, table: npt.NDArray[np.int32], sources: list[list[int]],
          chunk: int) -> tuple[float, npt.NDArray[np.int32]]:
    """CPU seconds of ``search`` over ``sources`` in batches of ``chunk``, and the tables."""
    t0 = time.process_time()
    out = np.concatenate([search(table, sources[i : i + chunk])
                          for i in range(0, len(sources), chunk)])
    return time.process_time() - t0, out


def main() -> None:
    """Time both searches and print one result line."""
    ap = CommandParser(description=__doc__.splitlines()[0])
    ap.add_argument("--goals", type=int, default=64)
    ap.add_argument("--blocks", type=int, nargs=2, default=(40, 33),
                    help="shelf blocks (x, y) of the generated warehouse")
    ap.add_argument("--map", type=Path, help="a MovingAI/LoRR map file instead")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    if args.map:
        grid = parse_map(args.map.read_text(encoding="utf-8").replace("E", "."),
                         source=str(args.map), name=args.map.name)
    else:
        grid = warehouse_map(args.blocks[0], args.blocks[1], 10, shelf_depth=2, aisle=2,
                             border=2, name="warehouse")
    free = np.flatnonzero(grid.free.ravel())
    goals = np.random.default_rng(args.seed).choice(free, size=args.goals).tolist()
    _multi_bfs(neighbour_table(grid), [[goals[0]]])  # compile (or load the cache) first
    rows = []
    for name, table, sources, chunk in (
            ("cells", neighbour_table(grid), [[g] for g in goals], 64),
            ("turning", turning_predecessor_table(grid),
             [[4 * g + h for h in range(4)] for g in goals], 16)):
        base_s, want = timed(numpy_bfs, table, sources, chunk)
        new_s, got = timed(_multi_bfs, table, sources, chunk)
        if not np.array_equal(want, got):
            raise SystemExit(f"{name}: the compiled tables differ from the baseline's")
        rows.append(f"{name} {new_s:.3f} s vs {base_s:.3f} s = {base_s / new_s:.1f}x")
    print(f"distance tables: {args.goals} goals on {grid!r} ({free.size} free cells), "
          f"compiled vs numpy (CPU, equal tables): " + "; ".join(rows))


if __name__ == "__main__":
    run_main("bench/distance.py", main)
