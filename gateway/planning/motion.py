"""Motion models by name, and the headings of the ``turning`` model (DESIGN section 2).

``omni``: a robot waits or moves to a free 4-neighbour, one timestep each. ``turning`` (MAPF
with turnings, the League of Robot Runners' MAPF_T convention): a robot's state is its cell
and heading; one timestep is a wait, a 90-degree turn clockwise or counter-clockwise in place,
or one cell forward along the heading. Occupancy, conflicts and the 1-robust rule are on cells
either way: a turning robot holds its cell. (No numpy here: the CLI reads these names at start.)
"""

from __future__ import annotations

from typing import Literal, get_args

Motion = Literal["omni", "turning"]
"""The name of a motion model."""

MOTIONS: tuple[Motion, ...] = get_args(Motion)
"""Every motion model, the default (``omni``) first."""

Heading = int
"""0 = east (+x), 1 = south (+y), 2 = west (-x), 3 = north (-y); clockwise is +1 (mod 4)."""

HeadedCell = tuple[int, int, int]
"""``(x, y, heading)``: a robot's pose under the ``turning`` model."""

HEADING_MOVES: tuple[tuple[int, int], ...] = ((1, 0), (0, 1), (-1, 0), (0, -1))
"""``HEADING_MOVES[h]`` is the ``(dx, dy)`` of one step forward with heading h."""

HEADING_NAMES: tuple[str, ...] = ("east", "south", "west", "north")
"""``HEADING_NAMES[h]`` names heading h."""

DEFAULT_START_HEADING: Heading = 0
"""The start heading of a robot whose instance gives none (MovingAI scenarios, mapf-IR and
LoRR agent files): east, as the League of Robot Runners' start kit starts its robots."""


def parse_heading(text: str) -> Heading:
    """A heading from ``0``-``3`` or its name (``east``, ``e``, ...); ``ValueError`` otherwise."""
    word = text.strip().lower()
    if word in ("0", "1", "2", "3"):
        return int(word)
    for h, name in enumerate(HEADING_NAMES):
        if word in (name, name[0]):
            return h
    raise ValueError(f"bad heading {text!r}: give 0-3 or east, south, west, north")


def turning_step(a: HeadedCell, b: HeadedCell) -> bool:
    """True if pose ``b`` follows pose ``a`` in one timestep of the ``turning`` model."""
    (x0, y0, h0), (x1, y1, h1) = a, b
    if (x0, y0) == (x1, y1):
        return (h1 - h0) % 4 in (0, 1, 3)
    dx, dy = HEADING_MOVES[h0 % 4]
    return h0 == h1 and (x1, y1) == (x0 + dx, y0 + dy)
