"""``fleetgate serve`` in lifelong mode as configured: every key the shift takes (map,
robots, scheduler, planner, planning period, horizon) is read, a bad value is refused with one
precise line, and the gateway runs the shift on the configured map (the task API places tasks
on its free cells, refuses its walls)."""

from __future__ import annotations

import asyncio
import subprocess
import sys
from pathlib import Path

import pytest

from gateway.planning.movingai import read_map
from gateway.runtime.mapstore import resolve
from gateway.server.config import ConfigError, load_config
from gateway.server.runs.lifelong import shift_from
from tests.server.task_client import call

EXAMPLE = Path(__file__).parents[2] / "deploy" / "gateway.lifelong.example.toml"
OPERATOR = {"Authorization": "Bearer CHANGE-ME-operator-token"}


def test_the_example_configures_every_key_of_a_shift() -> None:
    cfg = load_config(EXAMPLE, port=0)
    s = cfg.lifelong
    assert s is not None
    assert (s.map, s.robots, s.scheduler, s.max_wait_ms, s.planner, s.period_ms, s.window) == (
        "warehouse-small", 4, "shortest", 45_000.0, "pibt", 1000.0, 0)
    for name in ("horizon", "window"):  # the horizon's two names
        other = load_config(None, lifelong={name: 5}).lifelong
        assert other is not None and other.window == 5
    top = load_config(None, map="warehouse-small", lifelong={"robots": 3})
    assert top.shift_map == "warehouse-small"  # a top-level map is the shift's
    assert shift_from(top).grid.width == read_map(resolve("warehouse-small", "map")).width
    assert load_config(None, lifelong={"robots": 3}).shift_map is None  # not the default lab
    shift = shift_from(cfg)
    grid = read_map(resolve("warehouse-small", "map"))
    assert (shift.grid.width, shift.grid.height) == (grid.width, grid.height)
    assert (shift.grid.free == grid.free).all()
    assert len(set(shift.starts)) == 4 and all(grid.free.ravel()[c] for c in shift.starts)
    assert shift.tasks == ()  # task_list = false: only the WMS's


@pytest.mark.parametrize(("lifelong", "top", "message"), [
    ({"robots": 0}, {}, "lifelong.robots: Input should be greater than or equal to 1"),
    ({"scheduler": "fifo"}, {}, "lifelong.scheduler: Input should be 'shortest'"),
    ({"scheduler": "greedy"}, {}, "lifelong.scheduler: Input should be 'shortest'"),
    ({"planner": "cbs"}, {}, "lifelong.planner: Input should be 'pibt'"),
    ({"period_ms": 0}, {}, "lifelong.period_ms: Input should be greater than 0"),
    ({"horizon": -1}, {}, "lifelong.horizon: Input should be greater than or equal to 0"),
    ({"horizon": 2, "window": 3}, {}, "lifelong: give lifelong.window or horizon (its other "
                                      "name), not both"),
    ({"map": "warehouse-small", "problem": "p.json"}, {},
     "lifelong: give lifelong.problem (its own map) or lifelong.map, not both"),
    ({"map": "lab"}, {"map": "lab"}, "map = 'lab' and lifelong.map both give the shift's "
                                     "map: keep one"),
    ({"problem": "p.json"}, {"map": "lab"}, "map = 'lab' and lifelong.problem both give the "
                                            "shift's map: keep one"),
])
def test_a_bad_shift_configuration_is_one_precise_line(
        lifelong: dict[str, object], top: dict[str, object], message: str) -> None:
    with pytest.raises(ConfigError) as err:
        load_config(None, lifelong=lifelong, **top)
    assert str(err.value) == f"bad configuration: {message}"


@pytest.mark.parametrize(("lifelong", "message"), [
    ({"map": "no-such-map"}, "lifelong.map: no map named 'no-such-map'"),
    ({"map": "warehouse-small", "robots": 10_000}, "10000 robots do not fit on"),
])
def test_a_map_that_cannot_hold_the_shift_is_refused(tmp_path: Path,
                                                     lifelong: dict[str, object],
                                                     message: str) -> None:
    config = tmp_path / "shift.toml"
    config.write_text("port = 0\n[lifelong]\n" + "".join(
        f"{k} = {v!r}\n".replace("'", '"') for k, v in lifelong.items()))
    proc = subprocess.run([sys.executable, "-m", "gateway", "serve", "--config", str(config),
                           "--no-journal"], capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2
    assert len(proc.stderr.splitlines()) == 1 and message in proc.stderr, proc.stderr


def test_serve_runs_the_shift_on_the_configured_map(tmp_path: Path) -> None:
    config = tmp_path / "shift.toml"
    config.write_text(EXAMPLE.read_text().replace("port = 8080", "port = 0"))
    grid = read_map(resolve("warehouse-small", "map"))
    free = next(c for c in grid.free_cells())
    wall = next((x, y) for y in range(grid.height) for x in range(grid.width)
                if not grid.is_free((x, y)))
    proc = subprocess.Popen([sys.executable, "-m", "gateway", "serve", "--config", str(config),
                             "--no-journal", "--log-level", "WARNING"],
                            stderr=subprocess.PIPE, text=True)
    try:
        assert proc.stderr is not None
        line = proc.stderr.readline()
        port = int(line.split("ws://127.0.0.1:")[1].split("/")[0])

        async def main() -> tuple[int, int, str]:
            ok = await call(port, "POST", "/tasks", {"errands": [list(free)]}, OPERATOR)
            bad = await call(port, "POST", "/tasks", {"errands": [list(wall)]}, OPERATOR)
            return ok.status, bad.status, bad.json()["error"]

        ok, bad, error = asyncio.run(main())
        assert ok == 201 and bad == 422
        assert error == (f"errands.0: {list(wall)} is not a free cell of the map "
                         f"({grid.width} x {grid.height})")
    finally:
        proc.terminate()
        proc.wait(timeout=20)
