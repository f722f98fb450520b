"""Ctrl-C and the child processes of commands and bench scripts (:mod:`fleetgate.userio.children`).

A Ctrl-C on a terminal is SIGINT to the foreground process group. A Python child that gets it
while its interpreter still starts (importing ``site``, before any code of ours runs) prints
CPython's traceback: ``test_exit_table[bench-load-pipe]`` once failed so. So every bench
script starts its children in a session of their own, through one helper, and stops them
itself. Here real bench scripts are interrupted at several moments just after their first
child appeared, and each must end with 130, one line and no traceback, leaving no child
behind. The command's own start-up: a SIGINT held (blocked) across ``exec`` is delivered once
its guard is in place, at whatever moment it was sent. And after a Ctrl-C, an error that a
library made of the KeyboardInterrupt ends the command as interrupted too.
"""

from __future__ import annotations

import ast
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from fleetgate.userio.exits import EXIT_INTERRUPTED
from tests.procs import child_pids

ROOT = Path(__file__).resolve().parents[2]
SPAWNING = ("bench", "sim_clients")
"""Where children are started only through :mod:`fleetgate.userio.children`."""


def _hold_sigint() -> None:
    signal.signal(signal.SIGINT, signal.SIG_DFL)  # a shell's background job ignores it
    signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})  # until its guard: see above


def _alive(pid: int) -> bool:
    """Running (not gone, not a zombie waiting for its reaper)."""
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except OSError:
        return False
    return state != "Z"


@pytest.mark.parametrize("after_s", [0.0, 0.005, 0.015, 0.03, 0.06])
@pytest.mark.parametrize("argv", [
    ("bench/load.py", "--robots", "20", "--seconds", "5", "--json"),
    ("bench/crash.py", "--kills", "2", "--json"),
], ids=["load", "crash"])
def test_ctrl_c_as_a_bench_scripts_children_start_ends_it_with_one_line(
        argv: tuple[str, ...], after_s: float) -> None:
    proc = subprocess.Popen([sys.executable, *argv], cwd=ROOT, stdout=subprocess.DEVNULL,
                            stderr=subprocess.PIPE, stdin=subprocess.DEVNULL, text=True,
                            start_new_session=True, preexec_fn=_hold_sigint)
    seen: set[int] = set()
    try:
        deadline = time.monotonic() + 120.0
        while not (seen := child_pids(proc.pid)):
            assert proc.poll() is None and time.monotonic() < deadline, proc.stderr
            time.sleep(0.001)
        time.sleep(after_s)
        seen |= child_pids(proc.pid)
        os.killpg(proc.pid, signal.SIGINT)
        _, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
    assert "Traceback" not in err and "Fatal Python error" not in err, err
    assert proc.returncode == EXIT_INTERRUPTED, err
    assert err.splitlines() == [f"{argv[0]}: interrupted"], err
    assert [pid for pid in seen if _alive(pid)] == []  # stopped by the script, not orphaned


@pytest.mark.parametrize("after_s", [0.0, 0.002, 0.01, 0.05])
@pytest.mark.parametrize("argv", [
    ("-m", "fleetgate", "--version"),
    ("bench/monitor.py", "--robots", "20", "--samples", "2"),
    ("-c", "import sys; from gateway.cli import main; sys.exit(main(['--version']))"),
], ids=["fleetgate", "bench-script", "console-script"])
def test_a_ctrl_c_held_over_the_interpreters_start_is_delivered_at_the_guard(
        argv: tuple[str, ...], after_s: float) -> None:
    """Sent while CPython starts (where it would print a traceback) and held there, the
    SIGINT ends the command at its guard: 130 and one line, never the command's output."""
    proc = subprocess.Popen([sys.executable, *argv], cwd=ROOT, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, stdin=subprocess.DEVNULL, text=True,
                            start_new_session=True, preexec_fn=_hold_sigint)
    time.sleep(after_s)
    os.killpg(proc.pid, signal.SIGINT)
    out, err = proc.communicate(timeout=60)
    assert (proc.returncode, out) == (EXIT_INTERRUPTED, ""), (proc.returncode, out, err)
    prog = "fleetgate" if argv[0] != "bench/monitor.py" else argv[0]
    assert err == f"{prog}: interrupted\n", err


def test_children_are_started_only_through_the_helper() -> None:
    """No ``subprocess.Popen`` or ``asyncio.create_subprocess_*`` of its own in a bench
    script or the simulator: each starts its children through
    :func:`fleetgate.userio.children.spawn`."""
    own = []
    for top in SPAWNING:
        for path in sorted((ROOT / top).rglob("*.py")):
            for node in ast.walk(ast.parse(path.read_text())):
                if isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute) and (
                        node.func.attr == "Popen"
                        or node.func.attr.startswith("create_subprocess")):
                    own.append(f"{path.relative_to(ROOT)}:{node.lineno}")
    assert own == []


def test_a_child_runs_in_a_session_of_its_own_and_is_stopped_with_sigterm_then_sigkill(
        ) -> None:
    from fleetgate.userio import children

    with children.running([sys.executable, "-c", "import os; print(os.getsid(0))"],
                          stdout=subprocess.PIPE, text=True) as proc:
        out, _ = proc.communicate(timeout=60)
    assert int(out) == proc.pid != os.getsid(0)  # its own session, led by itself
    stubborn = children.spawn([sys.executable, "-c", "import signal, sys, time; "
                               "signal.signal(signal.SIGTERM, signal.SIG_IGN); "
                               "print(flush=True); time.sleep(60)"],
                              stdout=subprocess.PIPE, text=True)
    polite = children.spawn([sys.executable, "-c", "import sys, time; print(flush=True); "
                             "time.sleep(60)"], stdout=subprocess.PIPE, text=True)
    for child in (stubborn, polite):
        assert child.stdout is not None and child.stdout.readline() == "\n"  # running
    children.stop(stubborn, polite, grace_s=0.5)
    assert (stubborn.returncode, polite.returncode) == (-signal.SIGKILL, -signal.SIGTERM)


WRAPPED = '''
import signal, sys
from fleetgate.userio.exits import call, guard

def main():
    try:
        if "ctrl-c" in sys.argv:
            signal.raise_signal(signal.SIGINT)
        sum(range(10**6))  # the KeyboardInterrupt is raised in here
    except KeyboardInterrupt:  # as pydantic-core does, building a validator
        raise ValueError("Error building validator: KeyboardInterrupt") from None
    raise ValueError("a bug")

if "guard" in sys.argv:
    guard("prog")
    main()
sys.exit(call("prog", main))
'''


@pytest.mark.parametrize("where", ["call", "guard"])
def test_after_a_ctrl_c_an_error_a_library_made_of_it_ends_the_command_as_interrupted(
        where: str) -> None:
    """test_exit_table[serve-full] once printed a traceback: the SIGINT came while
    pydantic-core built a validator, and it raised SchemaError instead of KeyboardInterrupt.
    Without a Ctrl-C the same error is a bug and keeps its traceback."""
    interrupted = subprocess.run([sys.executable, "-c", WRAPPED, where, "ctrl-c"], cwd=ROOT,
                                 capture_output=True, text=True, timeout=60,
                                 preexec_fn=_hold_sigint)
    assert (interrupted.returncode, interrupted.stderr) == (EXIT_INTERRUPTED,
                                                            "prog: interrupted\n")
    bug = subprocess.run([sys.executable, "-c", WRAPPED, where], cwd=ROOT,
                         capture_output=True, text=True, timeout=60)
    assert bug.returncode == 1 and "Traceback" in bug.stderr
    assert bug.stderr.strip().endswith("ValueError: a bug")
