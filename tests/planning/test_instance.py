"""Instances from scenario and mapf-IR files: the checks that need the grid, with file:line."""

from __future__ import annotations

from pathlib import Path

import pytest

from gateway.planning.instance import load_instance, load_mapf_ir
from gateway.planning.movingai import MapFormatError

SHARED = Path(__file__).resolve().parents[2] / ".." / "shared" / "maps"

# 4x3 map: column 2 is a wall except for its bottom cell; (3, 0) is cut off by (2, 0), (3, 1).
MAP = "type octile\nheight 3\nwidth 4\nmap\n..@.\n..@@\n....\n"


def _scen(*lines: str) -> str:
    return "version 1\n" + "".join(f"0\tm.map\t4\t3\t{line}\t1\n" for line in lines)


@pytest.fixture
def files(tmp_path: Path) -> Path:
    (tmp_path / "m.map").write_text(MAP)
    return tmp_path


def _load(d: Path, scen: str, agents: int | None = None) -> None:
    (d / "s.scen").write_text(scen)
    load_instance(d / "m.map", d / "s.scen", agents)


def test_load_instance_takes_the_first_agents(files: Path) -> None:
    (files / "s.scen").write_text(_scen("0\t0\t3\t2", "1\t0\t0\t2", "0\t1\t1\t1"))
    inst = load_instance(files / "m.map", files / "s.scen", 2)
    assert inst.starts == ((0, 0), (1, 0))
    assert inst.goals == ((3, 2), (0, 2))
    assert inst.num_agents == 2
    assert inst.name == "s"
    assert inst.grid.name == "m.map"
    assert load_instance(files / "m.map", files / "s.scen").num_agents == 3


@pytest.mark.parametrize(("lines", "agents", "message"), [
    (["0\t0\t3\t2"], 2, "s.scen:2: 2 agents asked, the file lists only 1"),
    (["0\t0\t1\t1", "4\t0\t0\t2"], None, "s.scen:3: start (4, 0) is outside the 4x3 map"),
    (["0\t0\t1\t-1"], None, "s.scen:2: goal (1, -1) is outside the 4x3 map"),
    (["2\t0\t0\t2"], None, "s.scen:2: start (2, 0) is on an obstacle"),
    (["0\t0\t2\t1"], None, "s.scen:2: goal (2, 1) is on an obstacle"),
    (["0\t0\t1\t1", "0\t0\t0\t2"], None,
     "s.scen:3: start (0, 0) is also the start of the agent on line 2"),
    (["0\t0\t1\t1", "0\t1\t1\t1"], None,
     "s.scen:3: goal (1, 1) is also the goal of the agent on line 2"),
    (["0\t0\t3\t0"], None, "s.scen:2: goal (3, 0) is not reachable from start (0, 0)"),
])
def test_bad_agents(files: Path, lines: list[str], agents: int | None, message: str) -> None:
    with pytest.raises(MapFormatError) as err:
        _load(files, _scen(*lines), agents)
    assert str(err.value) == f"{files}/{message}"


def test_scenario_for_another_map_size(files: Path) -> None:
    with pytest.raises(MapFormatError) as err:
        _load(files, "version 1\n0\tm.map\t32\t32\t0\t0\t1\t1\t1\n")
    assert str(err.value) == f"{files}/s.scen:2: scenario is for a 32x32 map, the map is 4x3"


def test_only_the_chosen_agents_are_checked(files: Path) -> None:
    (files / "s.scen").write_text(_scen("0\t0\t1\t1", "2\t0\t0\t2"))
    assert load_instance(files / "m.map", files / "s.scen", 1).num_agents == 1


def test_mapf_ir_finds_its_map_in_the_parent_folder(files: Path) -> None:
    sub = files / "instances"
    sub.mkdir()
    (sub / "i.txt").write_text("map_file=m.map\nagents=2\nseed=0\n0,0,3,2\n1,1,0,2\n")
    inst = load_mapf_ir(sub / "i.txt", 1)
    assert (inst.starts, inst.goals, inst.name) == (((0, 0),), ((3, 2),), "i")


def test_mapf_ir_missing_map(files: Path) -> None:
    (files / "i.txt").write_text("map_file=nowhere.map\n0,0,3,2\n")
    with pytest.raises(MapFormatError) as err:
        load_mapf_ir(files / "i.txt")
    assert str(err.value).startswith(f"{files}/i.txt:1: map_file 'nowhere.map' not found")


@pytest.mark.skipif(not SHARED.is_dir(), reason="../shared/maps is not present")
def test_shared_instances_load() -> None:
    inst = load_mapf_ir(SHARED / "mapf-IR-instances" / "arena_300agents_1.txt", 25)
    assert inst.num_agents == 25
    assert inst.grid.name == "arena.map"
    full = load_instance(SHARED / "random-32-32-20.map",
                         SHARED / "scen" / "random-32-32-20-random-1.scen")
    assert full.num_agents > 100
