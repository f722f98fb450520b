"""``fleetgate experiment`` argument handling: map and agent-count groups."""

from __future__ import annotations

import pytest

from experiments.campaign import PAPER_GROUPS
from experiments.cmd_experiment import parse_groups
from gateway.runtime.exits import UsageError


def test_paper_groups_are_the_papers_1300_experiments() -> None:
    groups = parse_groups(None, None, paper=True)
    assert groups == list(PAPER_GROUPS)
    # 20 instances x 5 seeds per group: 13 groups -> 1300 experiments.
    assert len(groups) * 20 * 5 == 1300
    assert parse_groups(["arena"], None, paper=True) == [("arena", n) for n in (10, 15, 20, 25)]


def test_common_and_per_map_counts() -> None:
    assert parse_groups(["lab", "arena"], ["5,10", "arena=20", "arena=25"], paper=False) == [
        ("lab", 5), ("lab", 10), ("arena", 20), ("arena", 25)]
    assert parse_groups(["lab"], ["5", "5,10"], paper=False) == [("lab", 5), ("lab", 10)]


@pytest.mark.parametrize(("maps", "agents", "message"), [
    (None, ["5"], "--maps is required"),
    (["lab"], None, "no agent counts for map 'lab'"),
    (["lab"], ["five"], "not a comma-separated list"),
    (["lab"], ["0"], "positive"),
    (["lab"], ["arena=5"], "not in --maps: arena"),
])
def test_bad_groups(maps: list[str] | None, agents: list[str] | None, message: str) -> None:
    with pytest.raises(UsageError, match=message):
        parse_groups(maps, agents, paper=False)


def test_the_papers_totals_computed_as_ours_are() -> None:
    from experiments.cmd_experiment import PAPER, PAPER_MAP_MEANS

    maps = ("lab", "arena", "room-32-32-4", "random-32-32-20")
    means = [sum(float(PAPER[m][k].split()[0]) for m in maps) / 4 for k in ("mp", "mr")]
    # Slack's printed total is the mean of its maps; random's (7.00) is not: 7.81.
    assert PAPER_MAP_MEANS.startswith(f"{means[0]:.2f} / {means[1]:.2f} ")
    assert PAPER_MAP_MEANS.split()[:3] == ["27.37", "/", "7.81"]
