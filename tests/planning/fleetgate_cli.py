"""Run the ``fleetgate`` command: as a real subprocess, or in this process (much faster)."""

from __future__ import annotations

import contextlib
import io
import os
import subprocess
import sys
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

from gateway.cli import main

FLEETGATE = Path(sys.executable).parent / "fleetgate"
REPO = Path(__file__).resolve().parents[2]
SHARED_MAPS = REPO / ".." / "shared" / "maps"


def run(*args: str, env: Mapping[str, str] | None = None,
        timeout: float = 120) -> subprocess.CompletedProcess[str]:
    """``fleetgate ARGS`` as a subprocess with extra environment variables; text output."""
    full_env = {**os.environ, **(env or {})}
    return subprocess.run([str(FLEETGATE), *args], capture_output=True, text=True,
                          env=full_env, timeout=timeout, check=False)


@dataclass(frozen=True)
class Result:
    """What an in-process run printed and returned."""

    returncode: int
    stdout: str
    stderr: str


def call(*args: str) -> Result:
    """``fleetgate ARGS`` through :func:`gateway.cli.main` in this process."""
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            code = main(list(args))
        except SystemExit as exc:  # argparse's own usage errors
            code = int(exc.code or 0)
    return Result(code, out.getvalue(), err.getvalue())
