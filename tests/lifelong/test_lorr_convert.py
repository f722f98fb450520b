"""The converter of LoRR 2023/2024 instances to the 2026 rules, on tiny hand-written
instances of each season (and a check on the shared 2026 problems when ../shared is there)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from gateway.planning.lorr import LorrFormatError
from gateway.planning.lorr_convert import DELAY_2026, convert
from tests.lifelong.test_lifelong_sim import SHARED

MAP = "type octile\nheight 2\nwidth 4\nmap\n.E.@\n..S.\n"  # free: 0 1 2, 4 5 6 7


def _instance(tmp_path: Path, problem: dict[str, object], tasks: str) -> Path:
    (tmp_path / "m.map").write_text(MAP, encoding="utf-8")
    (tmp_path / "a.agents").write_text("2\n0\n7\n", encoding="utf-8")
    (tmp_path / "t.tasks").write_text(tasks, encoding="utf-8")
    path = tmp_path / "p.json"
    path.write_text(json.dumps({"mapFile": "m.map", "agentFile": "a.agents",
                                "taskFile": "t.tasks", "teamSize": 2, **problem}),
                    encoding="utf-8")
    return path


def test_a_2023_instance_gets_counter_delays_and_a_revealed_pool(tmp_path: Path) -> None:
    path = _instance(tmp_path, {"numTasksReveal": 1, "taskAssignmentStrategy": "roundrobin"},
                     "3\n5\n2\n6\n")
    conv = convert(path)
    prob = conv.problem
    assert conv.season == 2023
    assert prob.tasks == ((5,), (2,), (6,))  # one errand each, as in 2023
    assert prob.starts == (0, 7) and prob.grid.free.sum() == 7
    assert prob.agent_counter == 3 and prob.num_tasks_reveal == 1.5
    assert prob.delay == DELAY_2026
    assert any("round-robin" in c for c in conv.changes)
    assert any(c.startswith("agentCounter 1 -> 3") for c in conv.changes)


def test_a_2024_instance_keeps_its_errands(tmp_path: Path) -> None:
    path = _instance(tmp_path, {"numTasksReveal": 1.5, "version": "2024 LoRR"},
                     "# version for LoRR 2024\n2\n1,6\n4,2,5\n")
    conv = convert(path, agent_counter=2)
    assert conv.season == 2024
    assert conv.problem.tasks == ((1, 6), (4, 2, 5))
    assert conv.problem.agent_counter == 2
    assert not any("numTasksReveal" in c or "round-robin" in c for c in conv.changes)
    assert any("no following" in c for c in conv.changes)


def test_bad_input_is_one_line(tmp_path: Path) -> None:
    path = _instance(tmp_path, {"numTasksReveal": 1.5}, "1\n3\n")  # 3 is an obstacle
    with pytest.raises(LorrFormatError, match=r"t\.tasks:2: location 3 is not a free cell"):
        convert(path)


def test_a_2026_problem_is_unchanged() -> None:
    path = SHARED / "random.domain" / "random-example_400.json"
    if not path.is_file():
        pytest.skip("../shared/lorr absent")
    conv = convert(path)
    assert conv.season == 2026 and conv.changes == ()
    assert conv.problem.agent_counter == 3 and conv.problem.delay.max_delay == 4
