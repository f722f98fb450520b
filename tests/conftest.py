"""Hypothesis profiles: ``ci`` is derandomised, so a CI run tries the same examples every time.

``HYPOTHESIS_PROFILE`` picks the profile; without it, ``ci`` when ``CI`` is set (as CI services
do) and ``dev`` otherwise. ``scripts/test.sh`` always uses ``ci``.

Every test gets its own state directory (``XDG_STATE_HOME``): a ``fleetgate serve`` it starts
journals there, never in the user's, and never resumes another test's run. Module- and
session-scoped fixtures (instantiated before it) get the test process's own directory.

Every test also gets back the logging set-up it started with: a command run in-process sets
the ``fleetgate`` loggers' handler to its stderr (``configure_logging``), which pytest closes
after that test, and a later test's log record would then print a logging error.
"""

from __future__ import annotations

import atexit
import logging
import os
import shutil
import tempfile
from collections.abc import Iterator
from pathlib import Path

import pytest
from hypothesis import HealthCheck, settings

_STATE = tempfile.mkdtemp(prefix="fleetgate-test-state-")
os.environ["XDG_STATE_HOME"] = _STATE
os.environ.pop("STATE_DIRECTORY", None)
atexit.register(shutil.rmtree, _STATE, True)


@pytest.fixture(autouse=True)
def _own_state_dir(tmp_path_factory: pytest.TempPathFactory,
                   monkeypatch: pytest.MonkeyPatch) -> None:
    state: Path = tmp_path_factory.mktemp("state")
    monkeypatch.setenv("XDG_STATE_HOME", str(state))
    monkeypatch.delenv("STATE_DIRECTORY", raising=False)

_CONFIGURED_LOGGERS = ("fleetgate", "asyncio", "websockets", "uvicorn")
"""The loggers ``gateway.server.logs.configure_logging`` sets up."""


@pytest.fixture(autouse=True)
def _own_logging() -> Iterator[None]:
    kept = [(lg, lg.handlers[:], lg.level, lg.propagate)
            for lg in map(logging.getLogger, _CONFIGURED_LOGGERS)]
    yield
    for lg, handlers, level, propagate in kept:
        lg.handlers[:] = handlers
        lg.setLevel(level)
        lg.propagate = propagate


settings.register_profile(
    "ci",
    derandomize=True,  # examples derived from each test's name: the same on every run
    deadline=None,  # per-example timing on a shared 2-core runner is noise, not a failure
    suppress_health_check=[HealthCheck.too_slow],
    print_blob=True,
)
settings.register_profile("dev", print_blob=True)
_DEFAULT = "ci" if os.environ.get("CI") else "dev"
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE") or _DEFAULT)
