"""Every command and bench script, as a user runs them, where things go wrong around them: its
output to ``/dev/full``, into a pipe whose reader is gone (``| head``), to a path where a file
stands in place of a folder, and Ctrl-C (SIGINT to its process group) after 1 s, or once the
command's guard is in place if it is still starting then (:func:`_hold_sigint`). Each ends
with the documented exit code (:mod:`fleetgate.userio.exits`), at most a line on stderr and
never a traceback, and a file it was asked to write is left as it was when the command did
not finish (``fleetgate.userio.files``). Real subprocesses, nothing mocked.

A row's ``argv`` holds ``{out}`` where the command writes a file (each case puts there a path
of its own: /dev/full, ``FILE/out``, a scratch file holding a previous output) and ``{file}``
for a path that must be a folder; without ``{out}`` the output is standard output. Commands
that run until stopped (``long``) get SIGINT in every case after their first second; the
others only in the SIGINT case, and may finish first (then exit 0 with their output whole,
also when the signal comes as the interpreter tears down: Python then drops it).
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import pytest

from fleetgate.userio.exits import (
    EXIT_BAD_INPUT,
    EXIT_BROKEN_PIPE,
    EXIT_FAILED,
    EXIT_INTERRUPTED,
    EXIT_NO_SOLUTION,
    EXIT_OK,
)

ROOT = Path(__file__).resolve().parents[2]
BENCHMARK_MAPS = ROOT.parent / "shared" / "maps"
DOCUMENTED = {EXIT_OK, EXIT_FAILED, EXIT_BAD_INPUT, EXIT_NO_SOLUTION, EXIT_INTERRUPTED,
              EXIT_BROKEN_PIPE}
SIGINT_AFTER_S = 1.0
STOP_WITHIN_S = 20.0
"""From SIGINT to exit (GRACE_S is 5 s; the rest is a loaded 2-core machine)."""
PREVIOUS = "a previous output\n"
LAB = ["--map", "lab", "--scen", "lab-random-1"]


@dataclass(frozen=True)
class Row:
    """One command of the table."""

    name: str
    argv: tuple[str, ...]
    """The command line after ``python`` (``-m fleetgate ...`` or ``bench/x.py ...``)."""
    folder: tuple[str, ...] | None = None
    """For a command without ``{out}``: a command line whose path argument ``{file}/x`` needs
    a folder where a file stands (an input or another output of the command)."""
    long: bool = False
    """Runs until stopped: every case ends with SIGINT after its first second."""
    code: int = EXIT_OK
    """Its exit code run as it is (2: it cannot reach what it needs, as the table runs it)."""
    previous: bool = True
    """``{out}`` is a file the command replaces (it starts with a previous output there); a
    journal or a log is added to instead, a trace moved aside (their own rules)."""


FG = ("-m", "fleetgate")
ROWS = [
    Row("version", (*FG, "--version"), folder=(*FG, "plan", *LAB, "--maps-dir", "{file}/x")),
    Row("help", (*FG, "--help"), folder=(*FG, "maps", "list", "--maps-dir", "{file}/x")),
    Row("plan", (*FG, "plan", *LAB, "--agents", "3", "--json"),
        folder=(*FG, "plan", "--instance", "{file}/x.json")),
    Row("maps-list", (*FG, "maps", "list"),
        folder=(*FG, "maps", "list", "--maps-dir", "{file}/x")),
    Row("maps-generate", (*FG, "maps", "generate", "random", "m", "--width", "8", "--height",
                          "8", "--out", "{out}", "--force")),
    Row("maps-download", (*FG, "maps", "download", "x", "--base-url", "http://127.0.0.1:9/",
                          "--timeout", "2"),
        folder=(*FG, "maps", "download", "x", "--dest", "{file}/x"), code=EXIT_BAD_INPUT),
    Row("protocol-schema", (*FG, "protocol", "schema", "-o", "{out}")),
    Row("conformance-list", (*FG, "conformance", "gateway", "--list"),
        folder=(*FG, "conformance", "gateway", "ws://127.0.0.1:9/ws", "--junit",
                "{file}/x.xml")),
    Row("conformance-robot-list", (*FG, "conformance", "robot", "--list"),
        folder=(*FG, "conformance", "robot", "--url", "ws://127.0.0.1:0/ws", "--junit",
                "{file}/x.xml", "--timeout", "1")),
    Row("serve", (*FG, "serve", "--port", "0", "--journal", "{out}"), long=True,
        previous=False),
    Row("simulate", (*FG, "simulate", *LAB, "--agents", "10", "--trace", "{out}")),
    Row("sim", (*FG, "sim", "--connect", "ws://127.0.0.1:9/ws", "--robots", "2"), long=True,
        folder=(*FG, "sim", "--tokens", "{file}/t.json")),
    Row("demo", (*FG, "demo", "--port", "0", "--speed", "4", "--trace", "{out}"), long=True,
        previous=False),
    Row("demo-lifelong", (*FG, "demo", "--lifelong", "--robots", "4", "--port", "0",
                          "--json", "--log-file", "{out}"), long=True, previous=False),
    Row("lifelong", (*FG, "lifelong", "--problem", "{problem}", "--ticks", "3000", "--output",
                     "{out}")),
    Row("experiment", (*FG, "experiment", "--maps", "lab", "--agents", "4", "--instances",
                       "2", "--seeds", "1", "--solver-time", "zero", "--out", "{out}",
                       "--no-progress")),
    Row("robot", ("-m", "robot_client", "--help"),
        folder=("-m", "robot_client", "--robot-id", "0", "--token", "t", "--grid-width", "2",
                "--grid-height", "2", "--no-camera", "--gateway-url", "wss://127.0.0.1:9/ws",
                "--ca-file", "{file}/ca.pem")),
    Row("tracecheck", ("-m", "tracecheck", "{trace}"),
        folder=("-m", "tracecheck", "{file}/t.jsonl")),
    Row("tracecheck-lorr", ("-m", "tracecheck.lorr", "--help"),
        folder=("-m", "tracecheck.lorr", "{file}/o.json", "--map", "{file}/m.map")),
    Row("bench-planner", ("bench/planner.py", "--maps-dir", "{maps}", "--no-baseline"),
        folder=("bench/planner.py", "--maps-dir", "{file}/x"), long=True),
    Row("bench-monitor", ("bench/monitor.py", "--robots", "20", "--samples", "2")),
    Row("bench-sim-speed", ("bench/sim_speed.py", "--agents", "5", "--runs", "2")),
    Row("bench-distance", ("bench/distance.py", "--goals", "3", "--blocks", "3", "3"),
        folder=("bench/distance.py", "--map", "{file}/m.map")),
    Row("bench-feed", ("bench/feed.py", "--robots", "20", "--repeat", "1", "--json")),
    Row("bench-following", ("bench/following.py", "--steps", "2", "--seeds", "1", "--json"),
        folder=("bench/following.py", "--lorr", "{file}/x")),
    Row("bench-lifelong", ("bench/lifelong.py", "--journal", "--robots", "10", "--seconds",
                           "30", "--json")),
    Row("bench-load", ("bench/load.py", "--robots", "20", "--seconds", "5", "--json"),
        folder=("bench/load.py", "--profile", "{file}/p.prof"), long=True),
    Row("bench-owner", ("bench/owner.py", "--robots", "20", "--steps", "3", "--json"),
        folder=("bench/owner.py", "--against", "{file}/x")),
    Row("bench-crash", ("bench/crash.py", "--kills", "2", "--json"), long=True),
    Row("bench-api", ("bench/api.py", "--clients", "4", "--seconds", "2", "--pairs", "1",
                      "--against", "."),
        folder=("bench/api.py", "--against", "{file}/x"), long=True),
    Row("bench-fuzz", ("bench/fuzz.py", "--frames", "2000"), long=True),
    Row("bench-demo-stays", ("bench/demo_stays.py", "--runs", "1")),
    Row("bench-stay-bound", ("bench/stay_bound.py", "{camp}", "--sample", "1", "--points",
                             "2", "--tables", "{out}"), previous=False),
    Row("bench-stay-info", ("bench/stay_info.py", "{camp}", "--sample", "1"),
        folder=("bench/stay_info.py", "{file}/x")),
    Row("bench-stay-frontier", ("bench/stay_frontier.py", "{file}"),
        folder=("bench/stay_frontier.py", "{file}/x"), code=EXIT_BAD_INPUT),
    Row("bench-faults", ("bench/faults.py", "--trials", "1", "--modes", "oneshot"), long=True),
]
NO_PATH = {"bench-monitor", "bench-sim-speed", "bench-feed", "bench-lifelong", "bench-crash",
           "bench-fuzz", "bench-demo-stays", "bench-faults"}
"""Scripts that take no path argument: no file can stand where they expect a folder."""
CASES = ("full", "pipe", "folder", "sigint")


def test_every_command_and_bench_script_is_in_the_table() -> None:
    from gateway.cli import build_parser

    sub = next(a for a in build_parser()._actions if a.dest == "command")
    commands = set(sub.choices or ())
    named = {r.argv[2] for r in ROWS if r.argv[:2] == FG and not r.argv[2].startswith("-")}
    assert commands <= named, commands - named
    scripts = {f"bench/{p.name}" for p in (ROOT / "bench").glob("*.py") if p.name != "__init__.py"}
    assert scripts <= {r.argv[0] for r in ROWS}, scripts - {r.argv[0] for r in ROWS}


@pytest.fixture(scope="module")
def scratch(tmp_path_factory: pytest.TempPathFactory) -> Path:
    tmp = tmp_path_factory.mktemp("exits")
    (tmp / "file").write_text("a file, not a folder\n")
    from gateway.planning.lorr import warehouse_blocks, warehouse_problem, write_problem

    shift = warehouse_problem(60, 0, warehouse_blocks(60))
    write_problem(tmp / "lorr", "wh", shift.grid, list(shift.starts), list(shift.tasks),
                  agent_counter=3)
    trace = subprocess.run([sys.executable, "-m", "fleetgate", "simulate", *LAB, "--agents",
                            "10", "--trace", str(tmp / "t.jsonl")], cwd=ROOT, check=True,
                           capture_output=True, timeout=120)
    assert trace.returncode == 0
    camp = subprocess.run([sys.executable, "-m", "fleetgate", "experiment", "--maps", "lab",
                           "--agents", "4", "--instances", "1", "--seeds", "1", "--solver-time",
                           "zero", "--intruder-stay", "uniform:1-30", "--out", str(tmp / "camp"),
                           "--no-progress"], cwd=ROOT, capture_output=True, timeout=120)
    assert camp.returncode == 0, camp.stderr
    return tmp


def _hold_sigint() -> None:
    """In the child before ``exec``: SIGINT acts by default (a shell starts background jobs
    with it ignored, and children inherit that), and is blocked until the command's guard is
    in place (:func:`fleetgate.userio.exits.guard` unblocks it): a Ctrl-C while CPython itself
    still starts, before any code of ours runs, is CPython's to report, with a traceback. A
    SIGINT sent earlier waits for that point instead of depending on the machine's load."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)
    signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})


@dataclass
class Outcome:
    code: int
    stderr: str
    stopped_s: float | None
    """Seconds from SIGINT to exit (None: no SIGINT was sent)."""


def _run(argv: list[str], stdout: int | str, sigint: bool, cwd: Path) -> Outcome:
    """Run ``python ARGV`` with stdout to a file path, or to a pipe whose reader is gone
    (``stdout == -1``); SIGINT its process group after 1 s if ``sigint`` and still running
    (delivered once its guard is in place: :func:`_hold_sigint`)."""
    read = write = None
    if stdout == -1:
        read, write = os.pipe()
        os.close(read)
        out: int = write
    else:
        out = os.open(str(stdout), os.O_WRONLY | os.O_CREAT | os.O_TRUNC)
    env = {**os.environ, "PYTHONPATH": str(ROOT), "FLEETGATE_MAPS": ""}
    try:
        proc = subprocess.Popen([sys.executable, *argv], stdout=out, stderr=subprocess.PIPE,
                                stdin=subprocess.DEVNULL, cwd=cwd, env=env, text=True,
                                start_new_session=True, preexec_fn=_hold_sigint)
    finally:
        os.close(out)
    stopped = None
    try:
        if sigint:
            try:
                proc.wait(SIGINT_AFTER_S)
            except subprocess.TimeoutExpired:
                os.killpg(proc.pid, signal.SIGINT)
                sent = time.monotonic()
                proc.wait(STOP_WITHIN_S)
                stopped = time.monotonic() - sent
        _, err = proc.communicate(timeout=240)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
    # killed by SIGINT (it came as the command was exiting): what a shell shows as 130
    code = EXIT_INTERRUPTED if proc.returncode == -signal.SIGINT else proc.returncode
    return Outcome(code, err or "", stopped)


def _argv(row: Row, case: str, scratch: Path, out: Path) -> list[str] | None:
    """The row's command line for ``case`` (None: the case does not apply as such)."""
    has_out = any("{out}" in a for a in row.argv)
    if case == "folder" and not has_out:
        if row.folder is None:
            return None
        args = row.folder
    else:
        args = row.argv
    target = {"full": "/dev/full", "folder": f"{scratch}/file/out"}.get(case, str(out))
    return [a.replace("{out}", target).replace("{file}", f"{scratch}/file")
            .replace("{trace}", f"{scratch}/t.jsonl").replace("{camp}", f"{scratch}/camp")
            .replace("{problem}", f"{scratch}/lorr/wh.json")
            .replace("{maps}", str(BENCHMARK_MAPS)) for a in args]


def _whole(text: str) -> bool:
    """A complete output: one JSON document, or JSON lines ending with a trace's summary."""
    try:
        json.loads(text)
        return True
    except ValueError:
        pass
    try:
        lines = [json.loads(line) for line in text.splitlines()]
    except ValueError:
        return False
    return bool(lines) and lines[-1].get("type") == "summary"


def _expected(row: Row, case: str, has_out: bool, outcome: Outcome) -> set[int]:
    if outcome.stopped_s is not None:
        # a SIGINT that comes as the interpreter tears down after a finished run is lost
        # (no Python code runs to raise it): 0, and its output file must then be whole
        finished = has_out and row.previous and not row.long
        if row.code != EXIT_OK or case in ("full", "folder"):
            # a slow start (a loaded machine: bench/load.py's imports alone take ~0.9 s
            # idle) may reach its refusal of the bad input just as the SIGINT comes
            return {EXIT_INTERRUPTED, EXIT_BAD_INPUT}
        return {EXIT_INTERRUPTED, EXIT_OK} if finished else {EXIT_INTERRUPTED}
    if row.code != EXIT_OK or case in ("full", "folder"):
        return {EXIT_BAD_INPUT}
    if case == "sigint":
        return {EXIT_OK}  # done within the second: a whole output
    # a closed pipe: noticed when the command prints (a file output may be all it writes)
    return {EXIT_OK, EXIT_BROKEN_PIPE} if has_out else {EXIT_BROKEN_PIPE}


@pytest.mark.parametrize("case", CASES)
@pytest.mark.parametrize("row", ROWS, ids=[r.name for r in ROWS])
def test_one_line_a_documented_code_and_no_half_written_file(row: Row, case: str,
                                                              scratch: Path,
                                                              tmp_path: Path) -> None:
    has_out = any("{out}" in a for a in row.argv)
    out = tmp_path / ("out" if row.name not in ("maps-generate", "experiment") else "d")
    if has_out and case != "folder" and row.previous:
        if row.name in ("maps-generate", "experiment"):
            out.mkdir()
        else:
            out.write_text(PREVIOUS)
    if "{maps}" in row.argv and case != "folder" and not BENCHMARK_MAPS.is_dir():
        pytest.skip("needs the benchmark maps in ../shared/maps")
    argv = _argv(row, case, scratch, out)
    if argv is None and row.name in NO_PATH:
        pytest.skip("the script takes no path")
    assert argv is not None, f"{row.name}: no command line for the {case} case"
    stdout: int | str = -1 if case == "pipe" else (
        "/dev/full" if case == "full" and not has_out else str(tmp_path / "stdout"))
    outcome = _run(argv, stdout, row.long or case == "sigint", ROOT)
    assert "Traceback" not in outcome.stderr, outcome.stderr
    assert "Exception ignored" not in outcome.stderr, outcome.stderr
    assert outcome.code in DOCUMENTED
    assert outcome.code in _expected(row, case, has_out, outcome), (outcome.code,
                                                                     outcome.stderr)
    if outcome.code == EXIT_BAD_INPUT:
        assert len(outcome.stderr.strip().splitlines()) >= 1
        assert outcome.stderr.strip().splitlines()[-1].count("\n") == 0
    if outcome.stopped_s is not None:
        assert outcome.stopped_s < STOP_WITHIN_S
    if has_out and row.previous and out.is_file():
        # interrupted: the previous output is as it was, no temporary file is left
        # beside it; finished: the output is whole (not the previous one)
        text = out.read_text(errors="replace")
        if outcome.code in (EXIT_OK, EXIT_BROKEN_PIPE):  # finished (its file, then stdout)
            assert _whole(text), (row.name, text[-200:])
        else:  # the previous output, or (interrupted as it ended) the whole new one
            assert text == PREVIOUS or _whole(text), (row.name, text[-200:])
        assert [p.name for p in tmp_path.iterdir() if p.name.endswith(".tmp")] == []
