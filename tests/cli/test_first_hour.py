"""What a new operator and integrator met in their first hour (issue 27, items 3, 4, 11, 12
and 13), each as they met it: real commands in subprocesses, a real TLS server."""

from __future__ import annotations

import asyncio
import json
import os
import re
import signal
import ssl
import subprocess
import sys
import time
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import pytest

from tests.procs import child_pids

ROOT = Path(__file__).resolve().parents[2]
FLEETGATE = [sys.executable, "-m", "fleetgate"]
LAB = ["--map", "lab", "--scen", "lab-random-1"]


def _default_sigint() -> None:
    signal.signal(signal.SIGINT, signal.SIG_DFL)  # a shell's background job ignores it


def _fleetgate(*args: str, cwd: Path = ROOT, timeout: float = 120) -> subprocess.CompletedProcess[
        str]:
    return subprocess.run([*FLEETGATE, *args], cwd=cwd, capture_output=True, text=True,
                          timeout=timeout, check=False, env={**os.environ, "FLEETGATE_MAPS": ""})


def _cpu_s(pid: int) -> float:
    """CPU seconds the process and its live descendants have used so far (user + system, from
    /proc): a benchmark's work may run in child processes (bench/load.py's gateway and robots)."""
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    except (FileNotFoundError, ProcessLookupError):  # it ended meanwhile
        return 0.0
    own = (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")
    return own + sum(_cpu_s(k) for k in child_pids(pid))


def _until_busy(proc: subprocess.Popen[str], wall_s: float, cpu_s: float = 1.0) -> None:
    """Waits ``wall_s`` and until the process (with its children) has used ``cpu_s`` of CPU:
    past its start-up (the interpreter and imports take about 0.5 s of CPU) and into its work,
    however loaded the machine is (at load 20 the start-up alone took over 3 s of wall time)."""
    deadline = time.monotonic() + wall_s
    while (time.monotonic() < deadline or _cpu_s(proc.pid) < cpu_s) and proc.poll() is None:
        time.sleep(0.05)


def _problem(directory: Path) -> Path:
    from gateway.planning.lorr import warehouse_blocks, warehouse_problem, write_problem

    shift = warehouse_problem(60, 0, warehouse_blocks(60))
    return write_problem(directory, "wh", shift.grid, list(shift.starts), list(shift.tasks),
                         agent_counter=3)


# ---------------------------------------------------------------------------- item 3, 4
def test_experiment_into_an_existing_file_is_one_line(tmp_path: Path) -> None:
    readme = tmp_path / "README.md"
    readme.write_text("mine\n")
    done = _fleetgate("experiment", "--maps", "lab", "--agents", "2", "--instances", "1",
                      "--seeds", "1", "--out", str(readme), "--no-progress")
    assert done.returncode == 2 and "Traceback" not in done.stderr
    assert done.stderr == f"fleetgate: cannot write into {readme}: it is a file, not a folder\n"
    assert readme.read_text() == "mine\n"


def test_ctrl_c_during_lifelong_leaves_the_previous_output_whole(tmp_path: Path) -> None:
    out = tmp_path / "out.json"
    out.write_text('{"previous": true}')
    proc = subprocess.Popen([*FLEETGATE, "lifelong", "--problem", str(_problem(tmp_path)),
                             "--ticks", "200000", "--output", str(out)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            preexec_fn=_default_sigint)
    _until_busy(proc, 3)
    assert proc.poll() is None  # still running: 200,000 ticks take minutes
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=30)
    assert proc.returncode == 130 and err == "fleetgate: interrupted\n"
    assert out.read_text() == '{"previous": true}'
    assert sorted(p.name for p in tmp_path.iterdir()) == ["agents", "maps", "out.json",
                                                          "tasks", "wh.json"]


@pytest.mark.parametrize("script", ["bench/fuzz.py", "bench/load.py"])
def test_ctrl_c_in_a_busy_benchmark_ends_it_within_seconds(script: str) -> None:
    """fuzz.py drew its hostile frames inside the event loop, which sees a signal only
    between callbacks: Ctrl-C took 27 s. Now 5 s at most (fleetgate.userio.exits.GRACE_S)."""
    proc = subprocess.Popen([sys.executable, script], cwd=ROOT, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, start_new_session=True,
                            preexec_fn=_default_sigint)
    _until_busy(proc, 6)  # well into its work (fuzz: drawing 5,000 messages; load: the baseline)
    assert proc.poll() is None
    os.killpg(proc.pid, signal.SIGINT)
    sent = time.monotonic()
    _, err = proc.communicate(timeout=60)
    assert time.monotonic() - sent < 8, err
    assert proc.returncode == 130 and "Traceback" not in err, err
    assert err.strip().splitlines()[-1].startswith(f"{script}: interrupted"), err


# ---------------------------------------------------------------------------- item 11
def test_sim_refuses_zero_robots_and_takes_one_literal_token() -> None:
    from sim_clients.cmd_sim import token_source

    done = _fleetgate("sim", "--robots", "0")
    assert done.returncode == 2 and done.stderr.count("\n") == 1
    assert "--robots 0 names no robot" in done.stderr
    assert token_source("secret-T")(3) == "secret-T"
    with pytest.raises(ValueError, match="tokens"):
        token_source("missing.json")


def test_sim_says_when_nothing_listens_and_stops_at_once_on_ctrl_c() -> None:
    import socket

    with socket.socket() as s:  # a port nobody listens on
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    proc = subprocess.Popen([*FLEETGATE, "sim", "--connect", f"ws://127.0.0.1:{port}/ws",
                             "--robots", "2"], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True, preexec_fn=_default_sigint)
    assert proc.stderr is not None
    line = proc.stderr.readline()  # the first thing it says
    assert line.startswith(f"fleetgate sim: no gateway answers at ws://127.0.0.1:{port}/ws ")
    assert "retrying every 1 s" in line
    proc.send_signal(signal.SIGINT)
    sent = time.monotonic()
    _, err = proc.communicate(timeout=30)
    assert proc.returncode == 130 and "Traceback" not in err
    assert time.monotonic() - sent < 5  # it took 8.8 s: the world waited 10 s for set_speed


async def _tls_server(certs: Any) -> tuple[Any, int]:
    from websockets.asyncio.server import serve

    ctx = ssl.create_default_context(ssl.Purpose.CLIENT_AUTH)
    ctx.load_cert_chain(certs.server_cert, certs.server_key)

    async def handler(ws: Any) -> None:
        await ws.wait_closed()

    server = await serve(handler, "127.0.0.1", 0, ssl=ctx)
    return server, server.sockets[0].getsockname()[1]


def test_sim_says_why_tls_verification_fails(tmp_path: Path) -> None:
    from tests.server.tls_certs import make_certs

    certs = make_certs(tmp_path)

    async def main() -> subprocess.CompletedProcess[str]:
        server, port = await _tls_server(certs)
        async with server:
            # no --ca: the system's CAs do not know the gateway's throwaway CA
            proc = await asyncio.create_subprocess_exec(
                *FLEETGATE, "sim", "--connect", f"wss://127.0.0.1:{port}/ws", "--robots", "1",
                stdout=subprocess.PIPE, stderr=subprocess.PIPE)
            out, err = await asyncio.wait_for(proc.communicate(), 60)
            return subprocess.CompletedProcess([], proc.returncode or 0, out.decode(),
                                               err.decode())

    done = asyncio.run(main())
    assert done.returncode == 2, done.stderr
    last = done.stderr.strip().splitlines()[-1]
    assert last.startswith("fleetgate sim: ") and "TLS" in last
    assert "CERTIFICATE_VERIFY_FAILED" in last or "certificate verify failed" in last


def test_one_robot_is_one_robot() -> None:
    from sim_clients.cmd_sim import robots_connected

    assert robots_connected(1) == "1 robot connected"
    assert robots_connected(10) == "10 robots connected"


# ---------------------------------------------------------------------------- item 13
def test_version() -> None:
    from importlib.metadata import version

    done = _fleetgate("--version")
    assert (done.returncode, done.stdout) == (0, f"fleetgate {version('fleetgate')}\n")


def test_tracecheck_rounds_times_and_points_a_lorr_output_to_its_checker(tmp_path: Path
                                                                         ) -> None:
    trace = tmp_path / "run.jsonl"
    assert _fleetgate("simulate", *LAB, "--agents", "10", "--trace", str(trace)).returncode == 0
    done = subprocess.run([sys.executable, "-m", "tracecheck", str(trace)], capture_output=True,
                          text=True, timeout=60, check=False)
    assert done.returncode == 0
    assert re.fullmatch(r"1 plan\(s\), \d+ actions, SOC \d+ ms, makespan \d+ ms: OK\n",
                        done.stdout), done.stdout
    problem = _problem(tmp_path)
    out = tmp_path / "out.json"
    assert _fleetgate("lifelong", "--problem", str(problem), "--ticks", "200", "--output",
                      str(out)).returncode == 0
    done = subprocess.run([sys.executable, "-m", "tracecheck", str(out)], capture_output=True,
                          text=True, timeout=60, check=False)
    assert done.returncode == 2 and done.stdout == ""
    assert done.stderr.count("\n") == 1 and "KeyError" not in done.stderr
    assert f"python -m tracecheck.lorr {out} --problem PROBLEM.json" in done.stderr
    done = subprocess.run([sys.executable, "-m", "tracecheck.lorr", str(out), "--problem",
                           str(problem)], capture_output=True, text=True, timeout=60,
                          check=False)
    assert done.returncode == 0, done.stderr
    finished = json.loads(out.read_text())["numTaskFinished"]
    assert done.stdout == f"60 robots, 200 ticks, {finished} tasks finished: OK\n"


def test_the_lorr_checker_fails_a_collision(tmp_path: Path) -> None:
    from tracecheck.lorr import main

    (tmp_path / "m.map").write_text("type octile\nheight 1\nwidth 3\nmap\n...\n")
    out = {"agentMaxCounter": 1, "start": [[0, 0, "E"], [0, 2, "W"]],
           "actualPaths": ["[(0,0,0,0,0):(F 1)]", "[(0,0,2,2,0):(F 1)]"]}
    (tmp_path / "o.json").write_text(json.dumps(out))
    assert main([str(tmp_path / "o.json"), "--map", str(tmp_path / "m.map")]) == 1


def test_experiment_off_a_terminal_says_how_far_it_is(tmp_path: Path) -> None:
    done = _fleetgate("experiment", "--maps", "lab", "--agents", "3", "--instances", "2",
                      "--seeds", "1", "--solver-time", "zero", "--out", str(tmp_path / "e"))
    assert done.returncode == 0, done.stderr
    assert re.search(r"^fleetgate experiment: instances 2/2, \d+ s$", done.stderr, re.M)
    assert re.search(r"^fleetgate experiment: experiments 2/2, \d+ s$", done.stderr, re.M)


SUMMARY = re.compile(r"run complete: SOC \d+ ms, makespan \d+ ms, \d+ replan\(s\), "
                     r"\d+ collisions")


def test_the_run_summary_is_one_line_for_cli_and_gui_runs() -> None:
    from sim_clients.cmd_demo import run_summary

    # a run the GUI started is summarised from the engine by the same function ...
    engine: Any = SimpleNamespace(summary=(57000.0, 9000.0),
                                  executor=SimpleNamespace(replans=1))
    assert run_summary(engine, 0) == ("run complete: SOC 57000 ms, makespan 9000 ms, "
                                      "1 replan(s), 0 collisions")
    # ... as the one the command started
    done = _fleetgate("demo", "--headless", "--port", "0", "--agents", "3", "--no-intruder",
                      "--speed", "10", timeout=180)
    assert done.returncode == 0, done.stderr
    (line,) = [ln for ln in done.stderr.splitlines() if ln.startswith("run complete")]
    assert SUMMARY.fullmatch(line), line


# ---------------------------------------------------------------------------- item 12
@pytest.mark.parametrize(("sig", "code"), [(signal.SIGINT, 130), (signal.SIGTERM, 0)])
def test_the_robot_client_stops_on_ctrl_c_with_130_and_on_sigterm_with_0(
        sig: signal.Signals, code: int) -> None:
    import pty

    controller, device = pty.openpty()  # a serial line the Kobuki driver can open
    try:
        proc = subprocess.Popen(
            [sys.executable, "-m", "robot_client", "--robot-id", "0", "--token", "t",
             "--grid-width", "2", "--grid-height", "2", "--serial-port", os.ttyname(device),
             "--no-camera", "--gateway-url", "ws://127.0.0.1:9/ws"],
            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
            preexec_fn=_default_sigint)
        assert proc.stderr is not None
        assert "lost or refused" in proc.stderr.readline()  # running: no gateway there
        proc.send_signal(sig)
        _, err = proc.communicate(timeout=30)
        assert proc.returncode == code and "Traceback" not in err
    finally:
        os.close(controller)
        os.close(device)
