"""The scale runs' instances: skipped cleanly without a copy of the LoRR archive
(``$FLEETGATE_LORR_ARCHIVE``), and converted to the 2026 rules when it is there."""

from __future__ import annotations

from pathlib import Path

import pytest

from gateway.planning.lorr_convert import convert
from sim_clients.lifelong_scale import (
    INSTANCES,
    archive_dir,
    million_warehouse,
    scale_line,
    scale_runs,
)


def test_absent_instances_are_reported_as_skipped(tmp_path: Path) -> None:
    runs = scale_runs(tmp_path, 600, 1, ["false"], list(INSTANCES))  # the command never runs
    assert [r["instance"] for r in runs] == list(INSTANCES)
    assert all("not under" in r["skipped"] for r in runs)
    assert scale_line(runs).count("skipped") == len(INSTANCES)


@pytest.mark.parametrize(("name", "robots", "shape"),
                         [("warehouse_large", 10_000, (140, 500)),
                          ("brc202d", 6_500, (481, 530))])
def test_archive_instances_convert(name: str, robots: int, shape: tuple[int, int]) -> None:
    path = archive_dir(None) / INSTANCES[name].path
    if not path.is_file():
        pytest.skip(f"{path} absent (set FLEETGATE_LORR_ARCHIVE to a copy of the archive)")
    conv = convert(path)
    assert conv.season == 2024
    assert conv.problem.team_size == robots and conv.problem.grid.free.shape == shape
    assert conv.problem.agent_counter == 3 and conv.problem.delay.p_delay > 0


def test_the_million_cell_warehouse() -> None:
    prob = million_warehouse()
    grid = prob.grid
    assert grid.free.shape == (1000, 1000) and int(grid.free.sum()) == 586_660
    assert prob.team_size == 10_000 and len(set(prob.starts)) == 10_000
    assert all(grid.free.ravel()[c] for c in prob.starts)
    stations = {t[0] for t in prob.tasks}
    assert len(stations) <= 500 and len(prob.tasks) == 40_000
    for station, shelf in prob.tasks[:200]:
        y, x = divmod(station, 1000)
        assert y in (0, 999) or x in (0, 999)  # on the outer ring
        y, x = divmod(shelf, 1000)
        assert grid.free[y, x] and not (grid.free[y - 1, x] and grid.free[y + 1, x])
    assert prob.agent_counter == 3 and prob.delay.p_delay > 0
