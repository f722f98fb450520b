"""LoRR 2023 and 2024 competition instances under the 2026 rules of the shared problems.

The 2023 and 2024 seasons ran one action per tick and no delays; 2023 gave each task one
errand and handed tasks to agents round-robin in file order (``taskAssignmentStrategy``), 2024
revealed ``numTasksReveal`` x ``teamSize`` tasks of several errands to a scheduler. The 2026
problems (``shared/lorr``) take ``agentCounter`` ticks per forward move or turn and draw
delays (``delayConfig``); a moving robot holds both cells of its move, so no robot follows
another into a cell it is leaving. :func:`convert` reads an instance of any season (map,
agents and task locations unchanged) and returns it under those rules with the list of what
changed, which is what makes a figure of one season comparable, or not, with another's.
"""

from __future__ import annotations

import dataclasses
import json
from dataclasses import dataclass
from pathlib import Path

from gateway.planning.lorr import DelayConfig, LorrFormatError, LorrProblem, read_problem

DELAY_2026 = DelayConfig(seed=0, min_delay=1, max_delay=4, event_model="bernoulli",
                         p_delay=0.01, duration_model="uniform")
"""The delays of the shared random-example_400 (the shared problems draw 1-30 tick delays)."""
AGENT_COUNTER_2026 = 3
"""Ticks per forward move or turn in all four shared 2026 problems."""
REVEAL_2026 = 1.5
"""``numTasksReveal`` of all four shared 2026 problems."""


@dataclass(frozen=True)
class Converted:
    """An instance under the 2026 rules: the problem, its season, and what changed."""

    problem: LorrProblem
    season: int
    changes: tuple[str, ...]


def season_of(data: dict[str, object]) -> int:
    """The season of a problem JSON: 2023 (``taskAssignmentStrategy``), 2026 (an
    ``agentCounter`` or a 2026 ``version``) or 2024 (anything else)."""
    version = str(data.get("version", ""))
    if "taskAssignmentStrategy" in data:
        return 2023
    if "agentCounter" in data or "2026" in version:
        return 2026
    return 2024


def convert(path: str | Path, *, agent_counter: int = AGENT_COUNTER_2026,
            delay: DelayConfig = DELAY_2026, reveal: float = REVEAL_2026) -> Converted:
    """Read the LoRR instance at ``path`` and put it under the 2026 rules (a 2026 problem is
    returned unchanged); :class:`~gateway.planning.lorr.LorrFormatError` for bad input."""
    p = Path(path)
    problem = read_problem(p)  # checks the files; the JSON is then known to be an object
    try:
        data = json.loads(p.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise LorrFormatError(f"{p}: cannot read: {exc}") from None
    season = season_of(data)
    if season == 2026:
        return Converted(problem, season, ())
    ticks = f"{agent_counter} ticks" if agent_counter != 1 else "1 tick"
    changes = [
        f"agentCounter 1 -> {agent_counter}: a forward move or a turn takes {ticks}, so T "
        f"ticks hold T/{agent_counter} actions where {season} had T",
        f"delays: none -> {delay.event_model} p={delay.p_delay:g} per robot and tick, "
        f"{delay.min_delay}-{delay.max_delay} ticks ({delay.duration_model})",
        "a moving robot holds both cells of its move: no following into a cell being left",
    ]
    if season == 2023:
        changes.append(f"tasks: one errand each, assigned round-robin in file order -> "
                       f"revealed {reveal:g} x teamSize at a time to the scheduler")
    elif problem.num_tasks_reveal != reveal:
        changes.append(f"numTasksReveal {problem.num_tasks_reveal:g} -> {reveal:g}")
    changes.append("map, agents and task locations unchanged (E and S tiles are free)")
    out = dataclasses.replace(problem, agent_counter=agent_counter, delay=delay,
                              num_tasks_reveal=reveal)
    return Converted(out, season, tuple(changes))
