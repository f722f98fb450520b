"""Run the installed ``fleetgate`` console script as a real subprocess."""

from __future__ import annotations

import os
import subprocess
import sys
from collections.abc import Mapping
from pathlib import Path

FLEETGATE = Path(sys.executable).parent / "fleetgate"
REPO = Path(__file__).resolve().parents[2]
SHARED_MAPS = REPO / ".." / "shared" / "maps"


def run(*args: str, env: Mapping[str, str] | None = None,
        timeout: float = 120) -> subprocess.CompletedProcess[str]:
    """``fleetgate ARGS`` with extra environment variables; output captured as text."""
    full_env = {**os.environ, **(env or {})}
    return subprocess.run([str(FLEETGATE), *args], capture_output=True, text=True,
                          env=full_env, timeout=timeout, check=False)
