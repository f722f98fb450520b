"""An independent checker of LoRR output JSON: imports nothing of the project.

It decodes ``actualPaths`` (``[(t,row,col,heading,counter):(A n,...)]`` windows), replays
every tick under LoRR's rules (a forward move or turn completes after ``agentMaxCounter``
ticks of that action; ``W`` makes no progress) and checks that robots stay on free cells,
each window's snapshot matches the replayed state, and no two robots ever hold the same cell
at the same tick (a robot in the middle of a move holds both cells; a robot holds a cell from
the first tick of its move into it until the last tick of its move out of it).

Run it as ``python -m tracecheck.lorr OUT.json --problem PROBLEM.json`` (or ``--map FILE.map``).
"""

from __future__ import annotations

import argparse
import json
import re
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from fleetgate.userio.exits import CommandParser, UsageError, call, guard

_WINDOW = re.compile(r"\[\((\d+),(\d+),(\d+),(\d+),(\d+)\):\(([^)]*)\)\]")
_STEP = {0: (0, 1), 1: (1, 0), 2: (0, -1), 3: (-1, 0)}  # heading -> (drow, dcol)
_OMNI = {"e": (0, 1), "s": (1, 0), "w": (0, -1), "n": (-1, 0)}


def read_free(map_text: str) -> list[list[bool]]:
    """Free tiles of a MovingAI/LoRR map (``.``, ``E``, ``S``, ``G`` are free)."""
    lines = map_text.splitlines()
    height = int(lines[1].split()[1])
    return [[ch in ".ESG" for ch in row] for row in lines[4 : 4 + height]]


def decode(path: str) -> list[tuple[int, int, int, int, int, list[str]]]:
    """Windows of one path string: (t, row, col, heading, counter, per-tick letters)."""
    out = []
    pos = 0
    for m in _WINDOW.finditer(path):
        if m.start() != pos:
            raise AssertionError(f"garbage in path string at {pos}: {path[pos:pos + 30]!r}")
        pos = m.end()
        letters: list[str] = []
        for run in m.group(6).split(","):
            letter, count = run.split()
            letters += [letter] * int(count)
        t, row, col, heading, counter = (int(m.group(i)) for i in range(1, 6))
        out.append((t, row, col, heading, counter, letters))
    if pos != len(path):
        raise AssertionError("trailing garbage in a path string")
    return out


def check_output(out: dict[str, Any], free: list[list[bool]]) -> int:
    """Replay ``out`` and raise AssertionError on any violation; returns the tick count."""
    counter_max = out["agentMaxCounter"]
    height, width = len(free), len(free[0])
    held: dict[tuple[int, int, int], int] = {}  # (tick, row, col) -> robot
    ticks = 0
    for robot, path in enumerate(out["actualPaths"]):
        windows = decode(path)
        row, col = out["start"][robot][0], out["start"][robot][1]
        heading, counter, t = 0, 0, 0
        target: tuple[int, int] | None = None  # the cell of a move in progress
        for wt, wr, wc, wh, wk, letters in windows:
            if (wt, wr, wc, wh, wk) != (t, row, col, heading, counter):
                raise AssertionError(f"robot {robot}: snapshot {(wt, wr, wc, wh, wk)} but the "
                                     f"replay is at {(t, row, col, heading, counter)}")
            for letter in letters:
                cells = {(row, col)}
                if letter == "F" or letter in _OMNI:
                    if letter == "F":
                        dr, dc = _STEP[heading]
                    else:
                        dr, dc = _OMNI[letter]
                    nr, nc = row + dr, col + dc
                    if not (0 <= nr < height and 0 <= nc < width and free[nr][nc]):
                        raise AssertionError(f"robot {robot} drives into {(nr, nc)} at {t}")
                    if target not in (None, (nr, nc)):
                        raise AssertionError(f"robot {robot} changes its move at {t}")
                    cells.add((nr, nc))
                    target = (nr, nc)
                    counter += 1
                    if counter == counter_max:
                        row, col, counter, target = nr, nc, 0, None
                elif letter in "RC":
                    counter += 1
                    if counter == counter_max:
                        heading = (heading + (1 if letter == "R" else 3)) % 4
                        counter = 0
                elif letter != "W":
                    raise AssertionError(f"robot {robot}: unknown action {letter!r}")
                elif target is not None:
                    cells.add(target)  # paused in the middle of a move
                for cell in cells:
                    other = held.setdefault((t, *cell), robot)
                    if other != robot:
                        raise AssertionError(
                            f"robots {other} and {robot} both hold {cell} at tick {t}")
                t += 1
        ticks = max(ticks, t)
    return ticks


def _read_json(path: Path, what: str) -> Any:
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except OSError as exc:
        raise UsageError(f"cannot read the {what} {path}: {exc.strerror}") from None
    except json.JSONDecodeError as exc:
        raise UsageError(f"the {what} {path} is not JSON: {exc.msg} (line {exc.lineno})"
                         ) from None


def _map_file(args: argparse.Namespace) -> Path:
    if (args.map is None) == (args.problem is None):
        raise UsageError("give exactly one of --problem PROBLEM.json and --map FILE.map")
    if args.map is not None:
        return Path(args.map)
    problem = _read_json(args.problem, "problem")
    if not isinstance(problem, dict) or not isinstance(problem.get("mapFile"), str):
        raise UsageError(f"the problem {args.problem} has no mapFile")
    return Path(args.problem).parent / problem["mapFile"]


def _check(argv: Sequence[str] | None) -> int:
    parser = CommandParser(
        prog="python -m tracecheck.lorr",
        description="Replay a LoRR output JSON (fleetgate lifelong --output) under LoRR's "
                    "rules and check it: robots on free cells, snapshots matching the replay, "
                    "no two robots on one cell at a tick. Exit 1 on a violation.")
    parser.add_argument("output", type=Path, help="the LoRR output JSON")
    parser.add_argument("--problem", type=Path, help="the LoRR problem JSON (its mapFile)")
    parser.add_argument("--map", type=Path, help="or the map file itself")
    args = parser.parse_args(argv)
    path = _map_file(args)
    try:
        free = read_free(path.read_text(encoding="utf-8"))
    except OSError as exc:
        raise UsageError(f"cannot read the map {path}: {exc.strerror}") from None
    except (IndexError, ValueError):
        raise UsageError(f"{path} is no MovingAI map") from None
    out = _read_json(args.output, "LoRR output")
    if not isinstance(out, dict) or "actualPaths" not in out:
        raise UsageError(f"{args.output} is no LoRR output (no actualPaths); a fleetgate "
                         f"trace is checked by python -m tracecheck")
    try:
        ticks = check_output(out, free)
    except AssertionError as exc:
        print(f"error: {exc}")
        print(f"{len(out['actualPaths'])} robots: FAILED")
        return 1
    except (KeyError, TypeError, ValueError, IndexError) as exc:
        raise UsageError(f"{args.output}: malformed LoRR output ({exc!r})") from None
    print(f"{len(out['actualPaths'])} robots, {ticks} ticks, "
          f"{out.get('numTaskFinished', '?')} tasks finished: OK")
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    """``python -m tracecheck.lorr OUT.json --problem P.json``: exit 0 if the output replays
    cleanly, 1 on a violation (printed), 2 on bad input."""
    return call("tracecheck.lorr", _check, argv)


if __name__ == "__main__":
    guard("tracecheck.lorr")
    sys.exit(main())
