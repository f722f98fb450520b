"""``fleetgate plan`` as a real subprocess: solutions checked by the validator, exit codes."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest

from gateway.planning.distance import distance_table
from gateway.planning.instance import Instance, load_instance, load_mapf_ir
from gateway.planning.plan import Plan
from gateway.planning.validate import plan_violations
from tests.planning.fleetgate_cli import SHARED_MAPS, call, run

SHIPPED = Path(__file__).resolve().parents[2] / "gateway" / "planning" / "maps"
needs_shared = pytest.mark.skipif(not SHARED_MAPS.is_dir(), reason="../shared/maps is absent")
KEYS = ["map", "motion", "robust", "optimal", "soc", "makespan", "runtime_s", "expanded_nodes",
        "agents"]


def _check_solution(out: dict[str, Any], inst: Instance) -> None:
    """The JSON of DESIGN section 3, its plan valid for ``inst`` and its figures consistent."""
    assert list(out) == KEYS
    assert (out["map"], out["motion"], out["robust"]) == (inst.grid.name, "omni", 1)
    assert [tuple(a["start"]) for a in out["agents"]] == list(inst.starts)
    assert [tuple(a["goal"]) for a in out["agents"]] == list(inst.goals)
    paths = [[tuple(c) for c in a["path"]] for a in out["agents"]]
    assert plan_violations(inst.grid, inst.starts, inst.goals, paths) == []
    plan = Plan.of(paths)
    assert (out["soc"], out["makespan"]) == (plan.soc, plan.makespan)
    lower = sum(int(distance_table(inst.grid, g)[inst.grid.index(s)])
                for s, g in zip(inst.starts, inst.goals, strict=True))
    assert out["soc"] >= lower
    assert out["runtime_s"] >= 0 and out["expanded_nodes"] >= 0


def test_plan_lab_15_agents_json() -> None:
    done = run("plan", "--map", "lab", "--scen", "lab-random-1", "--agents", "15", "--json")
    assert done.returncode == 0, done.stderr
    out = json.loads(done.stdout)
    _check_solution(out, load_instance(SHIPPED / "lab.map", SHIPPED / "lab-random-1.scen", 15))
    assert out["optimal"] is True


def test_fallback_gives_a_valid_plan_marked_not_optimal() -> None:
    # 20 robots on lab-random-3: CBS cannot finish in 0.3 s (it needs several seconds), so
    # without --fallback this exits 3; with it the prioritised planner answers.
    args = ("plan", "--map", "lab", "--scen", "lab-random-3", "--agents", "20", "--json",
            "--time-limit", "0.3")
    assert call(*args).returncode == 3
    done = call(*args, "--fallback", "30")
    assert done.returncode == 0, done.stderr
    out = json.loads(done.stdout)
    _check_solution(out, load_instance(SHIPPED / "lab.map", SHIPPED / "lab-random-3.scen", 20))
    assert out["optimal"] is False


def test_plan_human_summary() -> None:
    done = call("plan", "--map", "lab", "--scen", "lab-random-2", "--agents", "5")
    assert done.returncode == 0, done.stderr
    assert done.stdout.startswith("lab.map, 5 agents: SOC ")
    assert len(done.stdout.splitlines()) == 1


@pytest.mark.parametrize(("extra", "heading"), [((), 0), (("--start-heading", "south"), 1)])
def test_plan_turning_json(extra: tuple[str, ...], heading: int) -> None:
    # MovingAI scenarios give no start headings: east by default, or --start-heading.
    done = call("plan", "--map", "lab", "--scen", "lab-random-1", "--agents", "8", "--json",
                "--motion", "turning", *extra)
    assert done.returncode == 0, done.stderr
    out = json.loads(done.stdout)
    inst = load_instance(SHIPPED / "lab.map", SHIPPED / "lab-random-1.scen", 8)
    assert list(out) == KEYS
    assert (out["motion"], out["robust"], out["optimal"]) == ("turning", 1, True)
    starts = [tuple(a["start"]) for a in out["agents"]]
    assert starts == [(x, y, heading) for x, y in inst.starts]
    assert [tuple(a["goal"]) for a in out["agents"]] == list(inst.goals)
    plan = Plan.from_json("turning", [a["path"] for a in out["agents"]])
    assert plan_violations(inst.grid, starts, inst.goals, plan) == []
    assert (out["soc"], out["makespan"]) == (plan.soc, plan.makespan)
    omni = json.loads(call("plan", "--map", "lab", "--scen", "lab-random-1", "--agents", "8",
                           "--json").stdout)
    assert out["soc"] > omni["soc"]  # lab-random-1 needs turns: the omni optimum is lower
    human = call("plan", "--map", "lab", "--scen", "lab-random-1", "--agents", "8",
                 "--motion", "turning", *extra)
    assert human.stdout.startswith(f"lab.map, 8 agents, turning: SOC {out['soc']}, ")


@needs_shared
def test_plan_movingai_scenario_by_name() -> None:
    done = call("plan", "--maps-dir", str(SHARED_MAPS), "--map", "random-32-32-20", "--scen",
               "random-32-32-20-random-1", "--agents", "10", "--json")
    assert done.returncode == 0, done.stderr
    inst = load_instance(SHARED_MAPS / "random-32-32-20.map",
                         SHARED_MAPS / "scen" / "random-32-32-20-random-1.scen", 10)
    _check_solution(json.loads(done.stdout), inst)


@needs_shared
def test_plan_mapf_ir_instance() -> None:
    path = SHARED_MAPS / "mapf-IR-instances" / "arena_300agents_1.txt"
    done = call("plan", "--instance", str(path), "--agents", "10", "--json")
    assert done.returncode == 0, done.stderr
    out = json.loads(done.stdout)
    assert out["map"] == "arena.map"
    _check_solution(out, load_mapf_ir(path, 10))


def test_no_solution_in_time_exits_3(tmp_path: Path) -> None:
    # Two agents must swap ends of a 1-wide corridor: impossible, so the planner runs out of time.
    (tmp_path / "c.map").write_text("type octile\nheight 1\nwidth 4\nmap\n....\n")
    (tmp_path / "c.scen").write_text("version 1\n0\tc.map\t4\t1\t0\t0\t3\t0\t3\n"
                                     "0\tc.map\t4\t1\t3\t0\t0\t0\t3\n")
    done = run("plan", "--map", str(tmp_path / "c.map"), "--scen", str(tmp_path / "c.scen"),
               "--time-limit", "1", "--json")
    assert done.returncode == 3
    assert done.stdout == ""
    assert done.stderr.startswith("fleetgate: no solution")
    assert len(done.stderr.splitlines()) == 1


@pytest.mark.parametrize(("args", "reason"), [
    (["--map", "no-such-map", "--scen", "lab-random-1"], "no map named 'no-such-map' in "),
    (["--map", "lab", "--scen", "no-such-scen"], "no scen named 'no-such-scen' in "),
    (["--map", "lab", "--scen", "lab-random-1", "--agents", "0"], "--agents must be at least 1"),
    (["--map", "lab", "--scen", "lab-random-1", "--agents", "21"],
     "lab-random-1.scen:21: 21 agents asked, the file lists only 20"),
    (["--map", "lab", "--scen", "lab-random-1", "--time-limit", "0"],
     "--time-limit must be positive"),
    (["--map", "lab"], "give --map and --scen, or --instance"),
    (["--scen", "lab-random-1", "--instance", "x.txt"], "give either --scen or --instance"),
    (["--instance", "/nonexistent/i.txt"], "cannot read /nonexistent/i.txt: "),
    (["--map", "warehouse-small", "--scen", "lab-random-1"],
     "lab-random-1.scen:2: scenario is for a 14x10 map, the map is 23x14"),
    (["--map", "lab", "--scen", "lab-random-1", "--start-heading", "north"],
     "--start-heading needs --motion turning"),
    (["--map", "lab", "--scen", "lab-random-1", "--motion", "turning", "--start-heading", "up"],
     "--start-heading: bad heading 'up': give 0-3 or east, south, west, north"),
])
def test_bad_input_exits_2_with_one_line(args: list[str], reason: str) -> None:
    done = call("plan", *args)
    assert done.returncode == 2
    assert done.stderr.startswith("fleetgate: ")
    assert reason in done.stderr
    assert len(done.stderr.splitlines()) == 1


def test_malformed_map_file_reports_file_and_line(tmp_path: Path) -> None:
    (tmp_path / "bad.map").write_text("type octile\nheight 2\nwidth 2\nmap\n..\n.?\n")
    done = run("plan", "--map", str(tmp_path / "bad.map"), "--scen", "lab-random-1")
    assert done.stdout == ""
    assert done.returncode == 2
    assert done.stderr == f"fleetgate: {tmp_path}/bad.map:6: unknown tile '?' at column 1\n"
