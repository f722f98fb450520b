"""Plans, solutions and the planner's time budget: the types shared by planner and executor."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Protocol

from gateway.planning.grid import Cell

Path = tuple[Cell, ...]
"""``path[t]`` is the agent's cell at timestep t; after the last entry it stays there."""


def path_cost(path: Sequence[Cell]) -> int:
    """Cost of one agent: the last timestep at which it arrives at its goal and stays.

    Trailing repeats of the goal do not count, so ``[(0,0), (1,0), (1,0)]`` costs 1.
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

    @property
    def soc(self) -> int:
        """Sum of costs in timesteps."""
        return sum(path_cost(p) for p in self.paths)

    @property
    def makespan(self) -> int:
        """Largest agent cost in timesteps."""
        return max((path_cost(p) for p in self.paths), default=0)

    def position(self, agent: int, t: int) -> Cell:
        """Cell of ``agent`` at timestep ``t`` (its goal after the path ends)."""
        p = self.paths[agent]
        return p[t] if t < len(p) else p[-1]


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
