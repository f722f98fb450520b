"""``fleetgate demo --lifelong``: a warehouse shift over real websockets on loopback."""

from __future__ import annotations

import contextlib
import functools
import json
import os
import pty
import re
import signal
import socket
import subprocess
import sys
import threading
import time
import urllib.request
from collections.abc import Callable
from pathlib import Path

import pytest

from tracecheck import check_trace, read_trace

FLEETGATE = [sys.executable, "-m", "gateway"]


def test_a_headless_lifelong_demo_runs_a_shift_and_stops(tmp_path: Path) -> None:
    trace = tmp_path / "shift.jsonl"
    proc = subprocess.run(
        [*FLEETGATE, "demo", "--lifelong", "--headless", "--json", "--port", "0",
         "--robots", "8", "--speed", "5", "--seconds", "60", "--motion", "turning",
         "--trace", str(trace)],
        capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    out = json.loads(proc.stdout.strip().splitlines()[-1])
    assert out["robots"] == 8 and out["plan_s"] >= 60.0
    assert out["tasks_finished"] >= 1 and out["tasks_per_min"] > 0
    assert out["lost"] == 0 and out["duplicated"] == 0 and out["collisions"] == 0
    report = check_trace(read_trace(trace))
    assert report.errors == [] and report.collisions == []
    assert "fleetgate demo --lifelong: 8 robots on warehouse" in proc.stderr


def test_lifelong_demo_errors_are_one_line(tmp_path: Path) -> None:
    proc = subprocess.run([*FLEETGATE, "demo", "--lifelong", "--headless", "--port", "0",
                           "--problem", str(tmp_path / "missing.json")],
                          capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2
    assert proc.stderr.strip().splitlines() == [
        f"fleetgate: LoRR problem not found: {tmp_path / 'missing.json'}"]


STATUS = re.compile(r"t (\d+\.\d) s \| tasks \d+ \(\d+\.\d/min\) \| robots (\d)/4 \| "
                    r"queue \d+ \| (\w+)")


@pytest.mark.parametrize(("terminal", "sig"), [(True, signal.SIGINT), (False, signal.SIGTERM)])
def test_the_status_is_live_and_a_signal_ends_the_demo_cleanly(
        terminal: bool, sig: signal.Signals) -> None:
    """On a terminal, without ``--seconds``, the shift runs until Ctrl-C with its status line
    redrawn in place and moving on. On a pipe the status is a line every few seconds; after
    ``--seconds`` the shift stops and (not headless) the GUI stays up until SIGTERM. Either
    way: the summary line, no traceback, exit 130 after Ctrl-C and 0 after SIGTERM."""
    cmd = [*FLEETGATE, "demo", "--lifelong", "--port", "0", "--robots", "4", "--speed", "5"]
    if terminal:
        main, sub = pty.openpty()
        proc = subprocess.Popen([*cmd, "--headless"], stdout=subprocess.PIPE, stderr=sub)
        os.close(sub)
        read = functools.partial(os.read, main, 4096)
    else:
        proc = subprocess.Popen([*cmd, "--seconds", "30"], stdout=subprocess.PIPE,
                                stderr=subprocess.PIPE)
        assert proc.stderr is not None
        read = functools.partial(os.read, proc.stderr.fileno(), 4096)
    out = bytearray()

    def drain() -> None:
        with contextlib.suppress(OSError):  # EIO: the terminal's other end is closed
            while chunk := read():
                out.extend(chunk)

    def until(done: Callable[[str], bool]) -> str:
        deadline = time.monotonic() + 60
        while not done(text := out.decode(errors="replace")):
            assert time.monotonic() < deadline and proc.poll() is None, text
            time.sleep(0.1)
        return text

    reader = threading.Thread(target=drain, daemon=True)
    reader.start()
    try:
        # two different times on a terminal (it moves on), a line on a pipe (every 5 s)
        until(lambda t: len({m[1] for m in STATUS.finditer(t)
                             if m.group(2, 3) == ("4", "running")}) >= (2 if terminal else 1))
        if not terminal:
            text = until(lambda t: "serving the GUI until Ctrl-C" in t)
            port = re.findall(r"GUI at http://127\.0\.0\.1:(\d+)/", text)[0]
            with urllib.request.urlopen(f"http://127.0.0.1:{port}/login", timeout=10) as r:
                assert r.status == 200
        proc.send_signal(sig)
        # Ctrl-C: 130 (README), after the same clean stop; SIGTERM (a service manager): 0
        assert proc.wait(timeout=30) == (130 if sig == signal.SIGINT else 0)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    reader.join(10)
    text = out.decode(errors="replace")
    assert "Traceback" not in text and "shift started: Ctrl-C stops it" in text
    assert re.search(r"shift stopped: \d+ tasks in [\d.]+ s \([\d.]+/min\), \d+ actions, "
                     r"0 lost, 0 duplicated, 0 collisions", text), text
    assert ("\r\x1b[Kt " in text) == terminal  # redrawn in place only on a terminal
    if terminal:
        os.close(main)
    else:
        assert all(STATUS.fullmatch(line) or not line.startswith("t ")
                   for line in text.splitlines())


def test_a_busy_port_is_one_precise_line() -> None:
    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        port = busy.getsockname()[1]
        proc = subprocess.run([*FLEETGATE, "demo", "--lifelong", "--headless", "--port",
                               str(port)], capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2 and proc.stdout == ""
    assert proc.stderr.startswith(f"fleetgate: cannot listen on 127.0.0.1:{port}: ")
    assert proc.stderr.count("\n") == 1 and "address already in use" in proc.stderr
