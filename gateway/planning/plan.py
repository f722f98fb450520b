"""Plans, solutions and the planner's time budget: the types shared by planner and executor."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Protocol

from gateway.planning.grid import Cell
from gateway.planning.motion import HeadedCell, Motion

Path = tuple[Cell, ...]
"""``path[t]`` is the agent's cell at timestep t; after the last entry it stays there."""


def path_cost(path: Sequence[Cell] | Sequence[HeadedCell]) -> int:
    """Cost of one agent: the last timestep at which it arrives at its goal and stays.

    Trailing repeats of the goal do not count, so ``[(0,0), (1,0), (1,0)]`` costs 1. Under the
    ``turning`` model the entries are poses ``(x, y, heading)``: a turn on the goal counts.
    """
    t = len(path) - 1
    while t > 0 and path[t - 1] == path[t]:
        t -= 1
    return t


def trim_path(path: Sequence[Cell]) -> Path:
    """The path without trailing waits on its goal (its length is ``path_cost + 1``)."""
    return tuple(path[: path_cost(path) + 1])


@dataclass(frozen=True)
class Plan:
    """One path per agent, indexed like the agents of the instance.

    ``paths`` are cells under either motion model (occupancy is on cells). A ``turning`` plan
    also has ``headings[k][t]``, agent k's heading at timestep t, one per entry of
    ``paths[k]``; an ``omni`` plan has ``headings is None``.
    """

    paths: tuple[Path, ...]
    headings: tuple[tuple[int, ...], ...] | None = None

    def __post_init__(self) -> None:
        if self.headings is not None and [len(h) for h in self.headings] != [
                len(p) for p in self.paths]:
            raise ValueError("a turning plan needs one heading per path entry")

    @staticmethod
    def of(paths: Sequence[Sequence[Cell]]) -> Plan:
        """Build a plan from any sequences of ``(x, y)`` cells (trailing goal waits trimmed)."""
        return Plan(tuple(trim_path([(int(x), int(y)) for x, y in p]) for p in paths))

    @staticmethod
    def of_poses(paths: Sequence[Sequence[HeadedCell]]) -> Plan:
        """Build a ``turning`` plan from sequences of ``(x, y, heading)`` poses (trailing
        waits trimmed)."""
        poses = [[(int(x), int(y), int(h)) for x, y, h in p] for p in paths]
        trimmed = [p[: path_cost(p) + 1] for p in poses]
        return Plan(tuple(tuple((x, y) for x, y, _ in p) for p in trimmed),
                    tuple(tuple(h for _, _, h in p) for p in trimmed))

    @property
    def motion(self) -> Motion:
        """``"turning"`` if the plan has headings, else ``"omni"``."""
        return "omni" if self.headings is None else "turning"

    def poses(self, agent: int) -> tuple[HeadedCell, ...]:
        """Agent's path as ``(x, y, heading)`` poses (``turning`` plans only)."""
        if self.headings is None:
            raise ValueError("an omni plan has no headings")
        return tuple((x, y, h) for (x, y), h in
                     zip(self.paths[agent], self.headings[agent], strict=True))

    def json_paths(self) -> list[list[list[int]]]:
        """Paths as JSON lists: ``[x, y]`` entries (``omni``) or ``[x, y, heading]``
        (``turning``)."""
        if self.headings is None:
            return [[[x, y] for x, y in p] for p in self.paths]
        return [[list(pose) for pose in self.poses(k)] for k in range(len(self.paths))]

    @staticmethod
    def from_json(motion: object, paths: object) -> Plan:
        """The plan of a solution's ``motion`` and agents' ``path`` lists (DESIGN section 3).

        Raises ``ValueError`` with a one-line reason on anything malformed.
        """
        if motion not in ("omni", "turning"):
            raise ValueError(f"motion must be \"omni\" or \"turning\", got {motion!r}")
        width = 2 if motion == "omni" else 3
        if not isinstance(paths, list):
            raise ValueError("paths must be a list")
        for k, path in enumerate(paths):
            if not isinstance(path, list) or not path:
                raise ValueError(f"agent {k}: path must be a non-empty list")
            for t, entry in enumerate(path):
                if (not isinstance(entry, list) or len(entry) != width
                        or not all(type(v) is int for v in entry)):
                    shape = "[x, y]" if width == 2 else "[x, y, heading]"
                    raise ValueError(f"agent {k} t={t}: {entry!r} is not {shape} of integers")
                if width == 3 and not 0 <= entry[2] <= 3:
                    raise ValueError(f"agent {k} t={t}: heading {entry[2]} is not 0-3")
        if motion == "omni":
            return Plan.of(paths)
        return Plan.of_poses(paths)

    def cost(self, agent: int) -> int:
        """The agent's cost (:func:`path_cost`, on poses for a ``turning`` plan)."""
        if self.headings is None:
            return path_cost(self.paths[agent])
        return path_cost(self.poses(agent))

    @property
    def soc(self) -> int:
        """Sum of costs in timesteps."""
        return sum(self.cost(k) for k in range(len(self.paths)))

    @property
    def makespan(self) -> int:
        """Largest agent cost in timesteps."""
        return max((self.cost(k) for k in range(len(self.paths))), default=0)

    def position(self, agent: int, t: int) -> Cell:
        """Cell of ``agent`` at timestep ``t`` (its goal after the path ends)."""
        p = self.paths[agent]
        return p[t] if t < len(p) else p[-1]

    def heading(self, agent: int, t: int) -> int:
        """Heading of ``agent`` at timestep ``t`` (``turning`` plans only)."""
        if self.headings is None:
            raise ValueError("an omni plan has no headings")
        h = self.headings[agent]
        return h[t] if t < len(h) else h[-1]


@dataclass(frozen=True)
class Solution:
    """A planner's answer: the plan plus how it was found."""

    plan: Plan
    optimal: bool
    expanded_nodes: int = 0


class Deadline(Protocol):
    """The planner's only view of time: the driver decides what "expired" means."""

    def expired(self) -> bool:
        """True once the planner must give up."""
        ...


class NeverExpires:
    """A deadline that never expires (tests, exhaustive searches)."""

    def expired(self) -> bool:
        """Always False."""
        return False


class NoSolution(Exception):
    """The planner proved there is no plan, or ran out of its deadline."""

    def __init__(self, reason: str, *, timed_out: bool = False) -> None:
        super().__init__(reason)
        self.timed_out = timed_out
