"""LoRR problem files: reading, clear errors, the CLI's exit codes."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from gateway.cli import main
from gateway.planning.lorr import LorrFormatError, compress_path, read_problem, write_problem
from gateway.planning.movingai import format_map
from tests.lifelong.support import small_problem
from tracecheck.lorr import check_output, read_free


def _write(tmp_path: Path) -> Path:
    p = small_problem(1, robots=4, size=8)
    return write_problem(tmp_path, "tiny", p.grid, list(p.starts), list(p.tasks),
                         agent_counter=2, num_tasks_reveal=1.5, delay=p.delay)


def test_round_trip(tmp_path: Path) -> None:
    p = small_problem(1, robots=4, size=8)
    back = read_problem(_write(tmp_path))
    assert back.starts == p.starts and back.tasks == p.tasks
    assert back.agent_counter == 2 and back.num_tasks_reveal == 1.5
    assert back.delay == p.delay
    assert (back.grid.free == p.grid.free).all()


@pytest.mark.parametrize(("edit", "message"), [
    (lambda d: d.pop("teamSize"), "missing field 'teamSize'"),
    (lambda d: d.update(teamSize=99), "teamSize is 99"),
    (lambda d: d.update(agentCounter="3"), "'agentCounter' must be int"),
    (lambda d: d.update(delayConfig={"eventModel": "often"}), "eventModel must be"),
    (lambda d: d.update(mapFile="nope.map"), "cannot read"),
])
def test_bad_problem_fields(tmp_path: Path, edit, message: str) -> None:  # type: ignore[no-untyped-def]
    path = _write(tmp_path)
    data = json.loads(path.read_text())
    edit(data)
    path.write_text(json.dumps(data))
    with pytest.raises(LorrFormatError, match=message) as info:
        read_problem(path)
    assert "\n" not in str(info.value)


def test_bad_locations(tmp_path: Path) -> None:
    path = _write(tmp_path)
    tasks = tmp_path / "tasks" / "tiny.tasks"
    tasks.write_text("1\n5,999999\n")
    with pytest.raises(LorrFormatError, match=r"tiny.tasks:2: location 999999 is not a free"):
        read_problem(path)
    tasks.write_text("3\n5\n")
    with pytest.raises(LorrFormatError, match="says 3 tasks"):
        read_problem(path)


def test_cli_bad_input_exit_2(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = _write(tmp_path)
    path.write_text("{not json")
    assert main(["lifelong", "--problem", str(path), "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("fleetgate: ") and "not JSON" in err and err.count("\n") == 1
    assert main(["lifelong", "--problem", str(path), "--ticks", "0"]) == 2


def test_cli_run_prints_throughput(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = _write(tmp_path)
    out = tmp_path / "out.json"
    assert main(["lifelong", "--problem", str(path), "--ticks", "40", "--output", str(out),
                 "--planner-time", "zero", "--no-progress"]) == 0
    text = capsys.readouterr().out
    assert "tasks finished" in text and "per tick" in text and "ms per call" in text
    data = json.loads(out.read_text())
    assert data["makespan"] == 40 and len(data["actualPaths"]) == 4


def test_cli_delay_seed_and_wait_percentiles(tmp_path: Path,
                                             capsys: pytest.CaptureFixture[str]) -> None:
    path = _write(tmp_path)  # small_problem(1): delayConfig seed 1
    runs = {}
    for name, extra in (("file", []), ("same", ["--delay-seed", "1"]),
                        ("other", ["--delay-seed", "7"])):
        out = tmp_path / f"{name}.json"
        assert main(["lifelong", "--problem", str(path), "--ticks", "60", "--output", str(out),
                     "--planner-time", "zero", "--no-progress", *extra]) == 0
        runs[name] = json.loads(out.read_text())
    assert runs["same"]["delayIntervals"] == runs["file"]["delayIntervals"]
    assert runs["other"]["delayIntervals"] != runs["file"]["delayIntervals"]
    wait = runs["file"]["assignmentWait"]
    assert set(wait) == {"p50", "p90", "p99", "max"}
    assert 0 <= wait["p50"] <= wait["p90"] <= wait["p99"] <= wait["max"] <= 60
    assert "assignment wait p50" in capsys.readouterr().out
    assert main(["lifelong", "--problem", str(path), "--max-wait", "-1"]) == 2
    assert "--max-wait must be >= 0" in capsys.readouterr().err


def test_compress_path_runs_and_windows() -> None:
    p = small_problem(1, robots=1, size=8)
    loc = p.starts[0]
    row, col = divmod(loc, p.grid.width)
    text = compress_path(p.grid, [(loc, 0, 0), (loc, 1, 1)], "WWFFRW", 4)
    assert text == f"[(0,{row},{col},0,0):(W 2,F 2)][(4,{row},{col},1,1):(R 1,W 1)]"


def test_cli_offers_the_schedulers() -> None:
    from gateway.execution.lifelong.tasks import SCHEDULERS
    from sim_clients.cmd_lifelong import SCHEDULER_CHOICES

    assert sorted(SCHEDULER_CHOICES) == sorted(SCHEDULERS)


def test_cli_default_bound_is_the_runner_s() -> None:
    from sim_clients.cmd_lifelong import MAX_WAIT_TICKS as CLI
    from sim_clients.lifelong import MAX_WAIT_TICKS, LifelongConfig

    assert CLI == MAX_WAIT_TICKS == LifelongConfig(small_problem(1)).max_wait


def test_cli_default_lanes_are_the_runner_s() -> None:
    from sim_clients import cmd_lifelong, lifelong

    for name in ("LANES", "LANES_ROOMS", "DOORS", "CORRIDOR_LANES", "LNS_ROUNDS"):
        assert getattr(cmd_lifelong, name) == getattr(lifelong, name)


def test_cli_lanes_over_the_cells(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                  monkeypatch: pytest.MonkeyPatch) -> None:
    """Where the exact tables do not fit the planner's budget but a table of moves per robot
    does, ``--lanes`` runs (the corridors' lanes: a valid output) and ``--doors`` is refused;
    where neither fits, ``--lanes`` is refused too, in one line."""
    path = _write(tmp_path)
    prob = read_problem(path)
    cells = 2 * prob.team_size * int(prob.grid.free.sum())  # tables of moves just fit
    monkeypatch.setattr("sim_clients.lifelong.PLANNER_BUDGET", cells)
    out = tmp_path / "lanes.json"
    assert main(["lifelong", "--problem", str(path), "--ticks", "40", "--output", str(out),
                 "--planner-time", "zero", "--no-progress", "--lanes", "5"]) == 0
    assert check_output(json.loads(out.read_text()), read_free(format_map(prob.grid))) == 40
    capsys.readouterr()
    assert main(["lifelong", "--problem", str(path), "--no-progress", "--doors", "5"]) == 2
    assert "--doors needs the turning motion and a map whose exact tables fit 2 GB" in \
        capsys.readouterr().err
    monkeypatch.setattr("sim_clients.lifelong.PLANNER_BUDGET", cells - 1)
    assert main(["lifelong", "--problem", str(path), "--no-progress", "--lanes", "5"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("fleetgate: --lanes needs the turning motion and a map whose tables "
                          "of moves fit 2 GB (") and err.count("\n") == 1


def test_cli_lanes(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """``--lanes`` runs the guided planner (a valid output, with ``--lns`` too), and is refused
    without turning or below 0, in one line each (``--lns`` below 0 too)."""
    path = _write(tmp_path)
    out = tmp_path / "lanes.json"
    assert main(["lifelong", "--problem", str(path), "--ticks", "40", "--output", str(out),
                 "--planner-time", "zero", "--no-progress", "--lanes", "2", "--doors", "9",
                 "--lns", "30"]) == 0
    prob = read_problem(path)
    assert check_output(json.loads(out.read_text()), read_free(format_map(prob.grid))) == 40
    capsys.readouterr()
    for extra, want in ((["--lanes", "-1"], "--lanes must be >= 0, got -1"),
                        (["--lanes", "1", "--motion", "omni"], "--lanes needs --motion turning"),
                        (["--doors", "-2"], "--doors must be >= 0, got -2"),
                        (["--doors", "1", "--motion", "omni"], "--doors needs --motion turning"),
                        (["--lns", "-1"], "--lns must be >= 0, got -1")):
        assert main(["lifelong", "--problem", str(path), "--no-progress", *extra]) == 2
        err = capsys.readouterr().err
        assert err == f"fleetgate: {want}\n"
