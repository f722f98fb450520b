"""League of Robot Runners (LoRR) problem files: reader, and the compressed path format.

A problem is a JSON file (``mapFile``, ``agentFile``, ``taskFile`` relative to it, ``teamSize``,
``numTasksReveal``, ``agentCounter``, ``delayConfig``; see ``shared/lorr/Input_Output_Format.md``).
Locations are linearised as ``row * width + column``, which is :meth:`Grid.index` of the cell
``(column, row)``. The map is a MovingAI map whose tiles may also be ``E`` (emitter) or ``S``
(service point), both free. Agent and task files start with a count line (``#`` lines are
comments); a task line lists its errand locations in order.

Every reader error is a :class:`LorrFormatError` with a one-line ``file[:line]: reason``.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from gateway.planning.generators import warehouse_map
from gateway.planning.grid import Grid
from gateway.planning.movingai import MapFormatError, format_map, parse_map

ACTION_LETTERS = {"forward": "F", "cw": "R", "ccw": "C", "wait": "W"}
"""One letter per action in LoRR path strings (forward, clockwise, counter-clockwise, wait)."""


class LorrFormatError(ValueError):
    """Malformed LoRR problem input; the message is one line naming the file."""


@dataclass(frozen=True)
class DelayConfig:
    """The problem's ``delayConfig``: which robots get delayed each tick, and for how long."""

    seed: int = 0
    min_delay: int = 1
    max_delay: int = 1
    event_model: str = "bernoulli"  # or "poisson"
    p_delay: float = 0.0
    duration_model: str = "uniform"  # or "gaussian"
    gauss_mean_ratio: float = 0.5
    gauss_std_ratio: float = 0.22

    @property
    def mean_duration(self) -> float:
        """Mean ticks of one delay (the Gaussian's mean before rounding and clamping)."""
        if self.duration_model == "uniform":
            return (self.min_delay + self.max_delay) / 2
        return self.min_delay + (self.max_delay - self.min_delay) * self.gauss_mean_ratio


@dataclass(frozen=True)
class LorrProblem:
    """A LoRR problem: map, start locations (flat ids), task errands (flat ids) and rules."""

    grid: Grid
    starts: tuple[int, ...]
    tasks: tuple[tuple[int, ...], ...]
    num_tasks_reveal: float = 1.5
    agent_counter: int = 1
    delay: DelayConfig = DelayConfig()
    name: str = ""

    @property
    def team_size(self) -> int:
        """Number of robots."""
        return len(self.starts)


def _field(data: dict[str, Any], key: str, kind: type, source: str, default: Any = None) -> Any:
    if key not in data:
        if default is None:
            raise LorrFormatError(f"{source}: missing field {key!r}")
        return default
    value = data[key]
    ok = isinstance(value, kind) and not isinstance(value, bool) if kind is not bool \
        else isinstance(value, bool)
    if kind is float and isinstance(value, int) and not isinstance(value, bool):
        ok, value = True, float(value)
    if not ok:
        raise LorrFormatError(f"{source}: field {key!r} must be {kind.__name__}, got {value!r}")
    return value


def _delay_config(data: Any, source: str) -> DelayConfig:
    if data is None:
        return DelayConfig()
    if not isinstance(data, dict):
        raise LorrFormatError(f"{source}: 'delayConfig' must be an object")
    src = f"{source}: delayConfig"
    cfg = DelayConfig(
        seed=_field(data, "seed", int, src, 0),
        min_delay=_field(data, "minDelay", int, src, 1),
        max_delay=_field(data, "maxDelay", int, src, 1),
        event_model=_field(data, "eventModel", str, src, "bernoulli"),
        p_delay=_field(data, "pDelay", float, src, 0.0),
        duration_model=_field(data, "durationModel", str, src, "uniform"),
        gauss_mean_ratio=_field(data, "gaussMeanRatio", float, src, 0.5),
        gauss_std_ratio=_field(data, "gaussStdRatio", float, src, 0.22),
    )
    if cfg.min_delay <= 0 or cfg.max_delay < cfg.min_delay:
        raise LorrFormatError(f"{src}: need 0 < minDelay <= maxDelay")
    if not 0.0 <= cfg.p_delay <= 1.0:
        raise LorrFormatError(f"{src}: pDelay must be in [0, 1]")
    if cfg.event_model not in ("bernoulli", "poisson"):
        raise LorrFormatError(f"{src}: eventModel must be 'bernoulli' or 'poisson'")
    if cfg.duration_model not in ("uniform", "gaussian"):
        raise LorrFormatError(f"{src}: durationModel must be 'uniform' or 'gaussian'")
    return cfg


def _numbered_lines(path: Path) -> list[tuple[int, str]]:
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise LorrFormatError(f"{path}: cannot read: {exc}") from None
    return [(i, line.strip()) for i, line in enumerate(text.splitlines(), 1)
            if line.strip() and not line.lstrip().startswith("#")]


def _location(path: Path, lineno: int, text: str, grid: Grid) -> int:
    try:
        loc = int(text)
    except ValueError:
        raise LorrFormatError(f"{path}:{lineno}: {text!r} is not a location") from None
    if not 0 <= loc < grid.size or not grid.free.flat[loc]:
        raise LorrFormatError(f"{path}:{lineno}: location {loc} is not a free cell of the map")
    return loc


def _counted(path: Path, what: str) -> list[tuple[int, str]]:
    lines = _numbered_lines(path)
    if not lines:
        raise LorrFormatError(f"{path}: empty {what} file")
    lineno, head = lines[0]
    try:
        count = int(head)
    except ValueError:
        raise LorrFormatError(f"{path}:{lineno}: expected the number of {what}s") from None
    if count < 0 or count > len(lines) - 1:
        raise LorrFormatError(f"{path}:{lineno}: says {count} {what}s, "
                              f"the file has {len(lines) - 1}")
    return lines[1 : 1 + count]


def read_problem(path: str | Path) -> LorrProblem:
    """Read a LoRR problem JSON file and the map, agent and task files it names."""
    p = Path(path)
    source = str(p)
    try:
        data = json.loads(p.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError) as exc:
        raise LorrFormatError(f"{source}: cannot read: {exc}") from None
    except json.JSONDecodeError as exc:
        raise LorrFormatError(f"{source}: not JSON: {exc}") from None
    if not isinstance(data, dict):
        raise LorrFormatError(f"{source}: expected a JSON object")
    base = p.parent
    map_path = base / _field(data, "mapFile", str, source)
    try:
        text = map_path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise LorrFormatError(f"{map_path}: cannot read: {exc}") from None
    try:  # LoRR tiles E (emitter) and S (service point) are free
        grid = parse_map(text.replace("E", "."), source=str(map_path), name=map_path.name)
    except MapFormatError as exc:
        raise LorrFormatError(str(exc)) from None
    team = _field(data, "teamSize", int, source)
    if team <= 0:
        raise LorrFormatError(f"{source}: teamSize must be positive")
    agent_path = base / _field(data, "agentFile", str, source)
    agents = _counted(agent_path, "agent")
    if len(agents) < team:
        raise LorrFormatError(f"{agent_path}: {len(agents)} agents, teamSize is {team}")
    starts = [_location(agent_path, n, t, grid) for n, t in agents[:team]]
    seen: dict[int, int] = {}
    for k, loc in enumerate(starts):
        if loc in seen:
            raise LorrFormatError(f"{agent_path}: agents {seen[loc]} and {k} start at {loc}")
        seen[loc] = k
    task_path = base / _field(data, "taskFile", str, source)
    tasks = []
    for n, t in _counted(task_path, "task"):
        tasks.append(tuple(_location(task_path, n, s.strip(), grid) for s in t.split(",")))
    if not tasks:
        raise LorrFormatError(f"{task_path}: no tasks")
    reveal = _field(data, "numTasksReveal", float, source, 1.0)
    counter = _field(data, "agentCounter", int, source, 1)
    if not (reveal > 0 and math.isfinite(reveal)) or counter <= 0:
        raise LorrFormatError(f"{source}: numTasksReveal and agentCounter must be positive")
    return LorrProblem(grid=grid, starts=tuple(starts), tasks=tuple(tasks),
                       num_tasks_reveal=reveal, agent_counter=counter,
                       delay=_delay_config(data.get("delayConfig"), source), name=p.stem)


def compress_path(grid: Grid, snapshots: list[tuple[int, int, int]], letters: str,
                  window: int) -> str:
    """A robot's executed ticks in LoRR's compressed path format.

    ``letters[t]`` is the action letter of tick t; ``snapshots[i]`` is the robot's
    ``(location, heading, counter)`` at the start of tick ``i * window``. Each window is
    ``[(t,row,col,heading,counter):(A n,B m,...)]`` with runs of equal letters.
    """
    out = []
    for i, start in enumerate(range(0, len(letters), window)):
        loc, heading, counter = snapshots[i]
        chunk = letters[start : start + window]
        runs: list[str] = []
        j = 0
        while j < len(chunk):
            k = j
            while k < len(chunk) and chunk[k] == chunk[j]:
                k += 1
            runs.append(f"{chunk[j]} {k - j}")
            j = k
        row, col = divmod(loc, grid.width)
        out.append(f"[({start},{row},{col},{heading},{counter}):({','.join(runs)})]")
    return "".join(out)


def write_problem(directory: str | Path, name: str, grid: Grid, starts: list[int],
                  tasks: list[tuple[int, ...]], *, agent_counter: int = 1,
                  num_tasks_reveal: float = 1.0,
                  delay: DelayConfig = DelayConfig()) -> Path:
    """Write a problem in LoRR's layout (``NAME.json``, ``maps/``, ``agents/``, ``tasks/``)."""
    base = Path(directory)
    for sub in ("maps", "agents", "tasks"):
        (base / sub).mkdir(parents=True, exist_ok=True)
    (base / "maps" / f"{name}.map").write_text(format_map(grid), encoding="utf-8")
    (base / "agents" / f"{name}.agents").write_text(
        "\n".join([str(len(starts)), *map(str, starts)]) + "\n", encoding="utf-8")
    (base / "tasks" / f"{name}.tasks").write_text(
        "\n".join([str(len(tasks)), *(",".join(map(str, t)) for t in tasks)]) + "\n",
        encoding="utf-8")
    problem = {
        "mapFile": f"maps/{name}.map", "agentFile": f"agents/{name}.agents",
        "taskFile": f"tasks/{name}.tasks", "teamSize": len(starts),
        "numTasksReveal": num_tasks_reveal, "agentCounter": agent_counter, "agentSize": 1.0,
        "delayConfig": {"seed": delay.seed, "minDelay": delay.min_delay,
                        "maxDelay": delay.max_delay, "eventModel": delay.event_model,
                        "pDelay": delay.p_delay, "durationModel": delay.duration_model,
                        "gaussMeanRatio": delay.gauss_mean_ratio,
                        "gaussStdRatio": delay.gauss_std_ratio},
    }
    path = base / f"{name}.json"
    path.write_text(json.dumps(problem, indent=1), encoding="utf-8")
    return path


def warehouse_blocks(robots: int) -> tuple[int, int]:
    """Shelf blocks (x, y) of a :func:`warehouse_problem` with at least 12 free cells per
    robot (at least 3 x 4)."""
    bx = 3
    while True:
        by = bx + 1
        width, height = 12 * bx + 2, 4 * by + 2  # shelves 10 x 2, aisles 2, border 2
        if width * height - 20 * bx * by >= 12 * robots or bx >= 40:
            return bx, by
        bx += 1


def warehouse_problem(robots: int, seed: int, blocks: tuple[int, int] = (13, 25),
                      p_delay: float = 0.01) -> LorrProblem:
    """A generated warehouse (``blocks`` shelf blocks of 10 x 2 cells in x and y, aisles of 2;
    (13, 25): about 10,000 free cells, like MovingAI's warehouse-10-20-10-2-1) with random
    starts and ``4 * robots`` two-errand tasks between cells beside shelves (pick and drop
    stations)."""
    grid = warehouse_map(blocks[0], blocks[1], 10, shelf_depth=2, aisle=2, border=2,
                         name="warehouse")
    free = grid.free
    blocked = ~free
    near = np.zeros_like(free)
    near[1:, :] |= blocked[:-1, :]
    near[:-1, :] |= blocked[1:, :]
    stations = np.flatnonzero((near & free).ravel())
    return random_problem(grid, robots, seed, stations, p_delay)


def random_problem(grid: Grid, robots: int, seed: int,
                   stations: npt.NDArray[np.intp] | None = None, p_delay: float = 0.0
                   ) -> LorrProblem:
    """``robots`` on distinct random free cells of ``grid`` and ``4 * robots`` two-errand
    tasks between random ``stations`` (flat cell ids; None: every free cell), drawn with
    ``seed``; ValueError if the robots do not fit."""
    rng = np.random.default_rng(seed)
    cells = np.flatnonzero(grid.free.ravel())
    if robots > cells.size:
        raise ValueError(f"{robots} robots do not fit on {cells.size} free cells")
    starts = rng.choice(cells, size=robots, replace=False)
    tasks = tuple((int(a), int(b)) for a, b in rng.choice(
        cells if stations is None else stations, size=(4 * robots, 2)))
    delay = DelayConfig(seed=seed, min_delay=1, max_delay=4, p_delay=p_delay)
    return LorrProblem(grid=grid, starts=tuple(int(s) for s in starts), tasks=tasks,
                       num_tasks_reveal=1.5, agent_counter=1, delay=delay,
                       name=grid.name or "map")
