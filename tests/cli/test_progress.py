"""The terminal status line and the logs printed above it; the demo's status and summary
text; Ctrl-C during a demo run."""

from __future__ import annotations

import io
import logging
import re
import signal
import subprocess
import sys
import time

from gateway.commands.progress import StatusLine, ticking
from gateway.server.logs import configure_logging


class Terminal(io.StringIO):
    """A StringIO that says it is a terminal."""

    def isatty(self) -> bool:
        return True


def screen(raw: str) -> list[str]:
    """What a terminal shows for ``raw``: carriage return and erase-line applied."""
    lines = [""]
    for part in re.split(r"(\r\x1b\[K|\n)", raw):
        if part == "\n":
            lines.append("")
        elif part == "\r\x1b[K":
            lines[-1] = ""
        else:
            lines[-1] += part
    return lines


def test_messages_and_logs_go_above_the_live_status() -> None:
    out = Terminal()
    status = StatusLine(out)
    assert status.live
    status.set("t 1.0 s | robots done 0/3")
    configure_logging("WARNING", "text", stream=status.stream)
    logging.getLogger("fleetgate.engine").warning("replan found no plan", extra={"robot": 2})
    status.set("t 2.0 s | robots done 1/3")
    status.print("run complete: SOC 5000 ms")
    shown = screen(out.getvalue())
    assert re.fullmatch(r"\d\d:\d\d:\d\d WARNING fleetgate.engine: replan found no plan "
                        r"\(robot=2\)", shown[0]), shown
    assert shown[1:] == ["run complete: SOC 5000 ms", "t 2.0 s | robots done 1/3"]
    status.clear()
    assert screen(out.getvalue())[-1] == ""


def test_json_logs_on_request_and_nothing_live_on_a_pipe() -> None:
    out = io.StringIO()
    status = StatusLine(out)
    assert not status.live
    status.set("t 1.0 s")  # not written: a pipe gets finished lines only
    configure_logging("INFO", "json", stream=status.stream)
    logging.getLogger("fleetgate.gateway").info("hello")
    status.print("done")
    lines = out.getvalue().splitlines()
    assert lines[0].startswith('{"ts": ') and '"msg": "hello"' in lines[0]
    assert lines[1:] == ["done"]


def test_ticking_shows_elapsed_time_while_a_block_runs() -> None:
    out = Terminal()
    status = StatusLine(out)
    with ticking(status, lambda s: f"planning ... {s:.0f} s", period_s=0.01):
        time.sleep(0.05)
    assert "planning ... 0 s" in out.getvalue()
    assert screen(out.getvalue())[-1] == ""  # cleared afterwards


def test_ctrl_c_before_the_demo_run_completes_exits_130() -> None:
    proc = subprocess.Popen([sys.executable, "-m", "fleetgate", "demo", "--headless",
                             "--port", "0", "--agents", "3", "--no-intruder"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        assert proc.stderr is not None
        for line in proc.stderr:
            if "GUI at http" in line:
                break
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=30)
        assert proc.returncode == 130
        assert "interrupted before the run completed" in err
        assert "Traceback" not in err
    finally:
        proc.kill()
        proc.wait()
