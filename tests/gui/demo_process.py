"""A real ``fleetgate demo`` subprocess on a free port, and Chromium launch settings."""

from __future__ import annotations

import re
import subprocess
import sys
import threading
from pathlib import Path

from fleetgate.userio import children

CHROMIUM = Path("/usr/bin/chromium")
CHROMIUM_ARGS = [
    "--no-sandbox", "--disable-gpu", "--disable-background-networking",
    "--disable-component-update", "--disable-sync", "--no-first-run",
]
_URL = re.compile(r"GUI at (https?://\S+)")


class DemoProcess:
    """``fleetgate demo --port 0 ARGS`` serving the GUI; ``url`` is where (read from stderr:
    its login URL, which carries the run's operator token in the fragment)."""

    def __init__(self, *args: str, timeout_s: float = 30.0) -> None:
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "gateway", "demo", "--port", "0", *args],
            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
        self.lines: list[str] = []
        self._found = threading.Event()
        self.url = ""
        threading.Thread(target=self._drain, daemon=True).start()
        if not self._found.wait(timeout_s) or not self.url:
            self.stop()
            raise RuntimeError("fleetgate demo did not print its URL:\n" + "".join(self.lines))

    def _drain(self) -> None:
        assert self.proc.stderr is not None
        for line in self.proc.stderr:
            self.lines.append(line)
            m = _URL.search(line)
            if m and not self.url:
                self.url = m[1]
                self._found.set()
        self._found.set()  # the process ended

    def stop(self) -> None:
        """SIGTERM (the demo stops cleanly on it), SIGKILL after 10 s."""
        children.stop(self.proc, grace_s=10.0)

    def __enter__(self) -> DemoProcess:
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()

