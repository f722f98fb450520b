"""Action kinds and their durations (DESIGN section 2, turning motion model).

An action ``a_i^k`` goes from pose ``(path_k[i], heading_k[i])`` to ``(path_k[i+1],
heading_k[i+1])``. Under ``omni`` there are no headings: an action is a move or a wait. Under
``turning`` (heading 0 = east (+x), 1 = south (+y), 2 = west (-x), 3 = north (-y)) it is a
move (one cell forward along the held heading), a turn (90 degrees in place) or a wait.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Literal

from gateway.execution.errors import ExecutionError
from gateway.execution.params import PAPER
from gateway.planning.grid import Cell

ActionKind = Literal["move", "turn", "wait"]
KINDS: tuple[ActionKind, ...] = ("move", "turn", "wait")

HEADING_STEP: tuple[Cell, ...] = ((1, 0), (0, 1), (-1, 0), (0, -1))
"""The cell offset of a forward move for each heading 0..3 (east, south, west, north)."""


@dataclass(frozen=True, slots=True)
class ActionDurations:
    """The expected duration ``t_x`` of each action kind for one robot model (ms)."""

    move_ms: float = PAPER.action_ms
    turn_ms: float = PAPER.action_ms
    wait_ms: float = PAPER.action_ms

    def __post_init__(self) -> None:
        for kind in KINDS:
            value = getattr(self, f"{kind}_ms")
            if not (math.isfinite(value) and value > 0):
                raise ExecutionError(f"{kind} duration must be a positive number of ms, "
                                     f"got {value}")

    @staticmethod
    def uniform(ms: float) -> ActionDurations:
        """Every kind takes ``ms``."""
        return ActionDurations(ms, ms, ms)

    def of(self, kind: ActionKind) -> float:
        """The duration of an action of ``kind``."""
        return self.move_ms if kind == "move" else self.turn_ms if kind == "turn" \
            else self.wait_ms

    def as_dict(self) -> dict[str, float]:
        """``{"move": ms, "turn": ms, "wait": ms}`` (the trace's ``durations_ms``)."""
        return {kind: self.of(kind) for kind in KINDS}


def per_robot(durations: ActionDurations | Sequence[ActionDurations],
              n: int) -> tuple[ActionDurations, ...]:
    """One :class:`ActionDurations` per robot from one for all or a per-robot sequence."""
    if isinstance(durations, ActionDurations):
        return (durations,) * n
    out = tuple(durations)
    if len(out) != n:
        raise ExecutionError(f"expected action durations for {n} robots, got {len(out)}")
    return out


def action_kind(src: Cell, dst: Cell, h0: int | None, h1: int | None) -> ActionKind:
    """The kind of the action from ``(src, h0)`` to ``(dst, h1)``; ExecutionError if it is
    no legal action (a jump, a turn by other than 90 degrees, a move sideways or backwards,
    or a move that also turns)."""
    dx, dy = dst[0] - src[0], dst[1] - src[1]
    if h0 is None or h1 is None:
        if h0 != h1:
            raise ExecutionError(f"heading given on one side only: {h0} -> {h1}")
        if abs(dx) + abs(dy) > 1:
            raise ExecutionError(f"jumps from {src} to {dst}: only waits and 4-neighbour "
                                 "moves are actions")
        return "wait" if src == dst else "move"
    for h in (h0, h1):
        if h not in (0, 1, 2, 3):
            raise ExecutionError(f"heading must be 0..3 (east, south, west, north), got {h}")
    if src == dst:
        if h0 == h1:
            return "wait"
        if (h1 - h0) % 4 in (1, 3):
            return "turn"
        raise ExecutionError(f"turn from heading {h0} to {h1} on {src}: a turn is 90 degrees")
    if h0 != h1:
        raise ExecutionError(f"move from {src} to {dst} changes the heading {h0} -> {h1}: "
                             "a move keeps it (turn first)")
    if (dx, dy) != HEADING_STEP[h0]:
        raise ExecutionError(f"move from {src} to {dst} is not one cell forward along "
                             f"heading {h0} (that is {HEADING_STEP[h0]})")
    return "move"
