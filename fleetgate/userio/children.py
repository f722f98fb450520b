"""Child processes that a command or bench script starts and owns.

Each child runs in a session of its own (``start_new_session``), so a Ctrl-C on the terminal
(SIGINT to the foreground process group) reaches the parent only: a Python child still
starting would otherwise get it while its interpreter imports ``site``, before any code of
ours can catch it, and CPython prints a traceback. The parent stops its children itself, with
SIGTERM (a Python child ends at once, silently; ``fleetgate serve`` stops cleanly), then
SIGKILL after a grace period: when a :func:`running` block ends (interrupted or not), when
the interpreter exits, and when it ends through :mod:`fleetgate.userio.exits` without
Python's exit (no clean stop within ``GRACE_S`` of a Ctrl-C; an exception at the top). A
parent killed with SIGKILL leaves them running.
"""

from __future__ import annotations

import atexit
import contextlib
import signal
import subprocess
import threading
import time
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from typing import Any

STOP_GRACE_S = 10.0
"""From SIGTERM to SIGKILL when a child is stopped."""
REAP_S = 5.0
"""How long a SIGKILLed child is waited for. Bounded: another thread may be reaping it (a
blocking wait holds the child's wait lock), and a give-up must still end the process."""

_LIVE: set[subprocess.Popen[Any]] = set()
"""The children started by :func:`spawn` and not yet stopped or seen ended."""


def spawn(argv: Sequence[str], **popen: Any) -> subprocess.Popen[Any]:
    """Start ``argv`` (:class:`subprocess.Popen` with ``popen``) in a session of its own;
    it is stopped at the interpreter's exit if still running then."""
    started: list[subprocess.Popen[Any]] = []
    _spawn_into(started, argv, popen)
    return started[0]


def _spawn_into(started: list[subprocess.Popen[Any]], argv: Sequence[str],
                popen: dict[str, Any]) -> None:
    """:func:`spawn`, the child appended to ``started`` before a Ctrl-C can interrupt (one
    that comes meanwhile is raised after that, :func:`_interrupts_deferred`: else a
    KeyboardInterrupt inside :class:`subprocess.Popen` would lose a started child)."""
    for ended in [p for p in _LIVE if p.poll() is not None]:
        _LIVE.discard(ended)
    with _interrupts_deferred():
        proc: subprocess.Popen[Any] = subprocess.Popen(argv, start_new_session=True, **popen)
        _LIVE.add(proc)
        started.append(proc)


@contextmanager
def _interrupts_deferred() -> Iterator[None]:
    """A SIGINT during the block reaches the process's handler at its end instead. Python
    runs its signal handlers in the main thread only, so only there is a KeyboardInterrupt
    raised (the signal may arrive at any thread: blocking it in one defers nothing)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    came: list[int] = []
    previous = signal.signal(signal.SIGINT, lambda signum, frame: came.append(signum))
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)
        if came:
            signal.raise_signal(signal.SIGINT)


def stop(*procs: subprocess.Popen[Any], grace_s: float = STOP_GRACE_S) -> None:
    """SIGTERM every one of ``procs`` still running, SIGKILL what is left after ``grace_s``
    (counted for all together), and reap them."""
    for proc in procs:
        if proc.poll() is None:
            proc.terminate()
    deadline = time.monotonic() + grace_s
    for proc in procs:
        try:
            proc.wait(max(0.0, deadline - time.monotonic()))
        except subprocess.TimeoutExpired:
            _kill_and_reap(proc)
        _LIVE.discard(proc)


def _kill_and_reap(proc: subprocess.Popen[Any]) -> None:
    """SIGKILL ``proc`` and wait for it, at most :data:`REAP_S`."""
    proc.kill()
    with contextlib.suppress(subprocess.TimeoutExpired):
        proc.wait(REAP_S)


def kill(proc: subprocess.Popen[Any]) -> None:
    """SIGKILL ``proc`` (a crash, on purpose) and reap it."""
    if proc.poll() is None:
        _kill_and_reap(proc)
    _LIVE.discard(proc)


def stop_all(grace_s: float = STOP_GRACE_S) -> None:
    """:func:`stop` every child still registered."""
    stop(*list(_LIVE), grace_s=grace_s)


@contextmanager
def running(argv: Sequence[str], grace_s: float = STOP_GRACE_S,
            **popen: Any) -> Iterator[subprocess.Popen[Any]]:
    """:func:`spawn` for the block; :func:`stop` when it ends, however it ends (a Ctrl-C as
    it starts included)."""
    started: list[subprocess.Popen[Any]] = []
    try:
        _spawn_into(started, argv, popen)
        yield started[0]
    finally:
        stop(*started, grace_s=grace_s)


atexit.register(stop_all)
