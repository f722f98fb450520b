"""``fleetgate simulate``: the --json contract, the trace, exit codes. The main cases run the
installed console script as a real process; the input checks call ``gateway.cli.main``
in-process (the same parser and code, without paying the process start-up each time)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from gateway.cli import main
from tests.planning.fleetgate_cli import run
from tracecheck import check_trace, read_trace

KEYS = {"soc_ms", "makespan_ms", "plan_soc", "replans", "replan_at_ms", "solver_ms",
        "collisions"}
LAB = ("--map", "lab", "--scen", "lab-random-1", "--agents", "10")


def test_json_summary_and_checked_trace(tmp_path: Path) -> None:
    trace = tmp_path / "run.jsonl"
    proc = run("simulate", *LAB, "--seed", "4", "--intruder", "--policy", "slack",
               "--threshold-ms", "1000", "--solver-time", "zero", "--trace", str(trace),
               "--json")
    assert proc.returncode == 0, proc.stderr
    out = json.loads(proc.stdout)
    assert set(out) == KEYS
    assert out["collisions"] == 0 and out["solver_ms"] == 0
    records = read_trace(trace)
    report = check_trace(records)
    assert report.ok, report.errors
    assert records[-1] == {"type": "summary", "soc_ms": out["soc_ms"],
                           "makespan_ms": out["makespan_ms"]}
    assert report.plans == 1 + out["replans"]
    assert any(r["type"] == "intruder" for r in records)


def test_without_intruder_soc_is_the_plan_cost(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["simulate", *LAB, "--seed", "1", "--no-intruder", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["soc_ms"] == 1000 * out["plan_soc"]
    assert (out["replans"], out["replan_at_ms"]) == (0, None)


def test_same_seed_zero_solver_time_same_output_and_trace(tmp_path: Path) -> None:
    outs = []
    for name in ("a.jsonl", "b.jsonl"):
        proc = run("simulate", *LAB, "--seed", "9", "--policy", "random", "--solver-time",
                   "zero", "--trace", str(tmp_path / name), "--json")
        assert proc.returncode == 0, proc.stderr
        outs.append(proc.stdout)
    assert outs[0] == outs[1]
    assert (tmp_path / "a.jsonl").read_bytes() == (tmp_path / "b.jsonl").read_bytes()
    assert json.loads(outs[0])["replans"] == 1


def test_bad_input_exits_2_with_one_line(tmp_path: Path,
                                         capsys: pytest.CaptureFixture[str]) -> None:
    for args in (("--map", "no-such-map", "--scen", "lab-random-1"),
                 (*LAB, "--threshold-ms", "-5"),
                 (*LAB, "--trace", str(tmp_path / "missing-dir" / "t.jsonl"))):
        assert main(["simulate", *args, "--json"]) == 2, args
        out, err = capsys.readouterr()
        assert out == ""
        assert len(err.strip().splitlines()) == 1, err
    # argparse's own usage error
    assert main(["simulate", *LAB, "--solver-time", "soon"]) == 2
    assert "solver time" in capsys.readouterr().err


def test_no_plan_exits_3(tmp_path: Path) -> None:
    # two robots must swap ends of a one-cell-wide corridor: no plan exists
    (tmp_path / "corridor.map").write_text("type octile\nheight 1\nwidth 4\nmap\n....\n")
    (tmp_path / "corridor.scen").write_text(
        "version 1\n0\tcorridor.map\t4\t1\t0\t0\t3\t0\t3\n0\tcorridor.map\t4\t1\t3\t0\t0\t0\t3\n")
    proc = run("simulate", "--map", str(tmp_path / "corridor.map"), "--scen",
               str(tmp_path / "corridor.scen"), "--time-limit", "1", "--json")
    assert proc.returncode == 3, proc.stderr
    assert proc.stdout == ""
