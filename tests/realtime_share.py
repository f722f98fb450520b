"""A pytest plugin that sorts test functions by the clock they run on (``scripts/realtime_share.py``
loads it; off otherwise).

A test (its setup and call, and every fixture it uses, whatever that fixture's scope) is

- ``real`` if it ran something on the real clock: created a :class:`RealClock` (an in-process
  gateway, fleet or benchmark in real time), started a subprocess that runs a gateway or a
  browser (``serve``, ``demo`` or ``sim`` of the CLI, a ``bench/`` script, Chromium through
  Playwright), or waited for real time to pass (``time.sleep`` or ``asyncio.sleep`` for more
  than 0 s on a loop without virtual time);
- ``virtual`` if it ran in virtual time (created a :class:`VirtualClock` or a ``looptime`` loop)
  and nothing real;
- ``pure`` otherwise (no clock drives it: a computation, a parser, a subprocess that only
  computes).

Teardown is not counted (stopping a server may wait a little). Each worker appends one JSON
line per test to the file named by ``FLEETGATE_REALTIME_SHARE``.
"""

from __future__ import annotations

import asyncio
import json
import os
import subprocess
import sys
import time
from collections.abc import Callable, Generator, Iterable
from typing import Any

import pytest

_current: set[str] = set()
_by_fixture: dict[tuple[str, str], set[str]] = {}
_setup: dict[str, set[str]] = {}
_RUNS = {"serve", "demo", "sim"}


def _note(reason: str) -> None:
    _current.add(reason)


def _is_virtual_loop() -> bool:
    try:
        loop = asyncio.get_running_loop()
    except RuntimeError:
        return False
    return bool(getattr(loop, "looptime_on", False))


def _runs_a_clock(argv: Iterable[str]) -> bool:
    words = [str(a) for a in argv]
    return (any(w in _RUNS for w in words) or any("bench/" in w for w in words)
            or any("playwright" in w or "chrom" in w for w in words))


def _patch() -> None:
    import looptime

    from gateway.server.clock import RealClock, VirtualClock

    real_init, virtual_init = RealClock.__init__, VirtualClock.__init__
    sleep, asleep = time.sleep, asyncio.sleep
    popen_init = subprocess.Popen.__init__
    new_loop: Callable[..., Any] = looptime.new_event_loop

    def clock_init(self: RealClock, *args: Any, **kwargs: Any) -> None:
        _note("real clock")
        real_init(self, *args, **kwargs)

    def virtual_clock_init(self: VirtualClock, *args: Any, **kwargs: Any) -> None:
        _note("virtual clock")
        virtual_init(self, *args, **kwargs)

    def timed_sleep(secs: float) -> None:
        if secs > 0 and sys._getframe(1).f_globals.get("__name__") != "subprocess":
            _note("real sleep")  # (subprocess polls a child with a timeout this way)
        sleep(secs)

    async def loop_sleep(delay: float, result: Any = None) -> Any:
        if delay > 0 and not _is_virtual_loop():
            _note("real sleep")
        return await asleep(delay, result)

    def popen(self: subprocess.Popen[Any], args: Any, *rest: Any, **kwargs: Any) -> None:
        if _runs_a_clock([str(args)] if isinstance(args, str | bytes) else args):
            _note("real subprocess")
        popen_init(self, args, *rest, **kwargs)

    def virtual_loop(*args: Any, **kwargs: Any) -> Any:
        _note("virtual loop")
        return new_loop(*args, **kwargs)

    patches: list[tuple[object, str, object]] = [
        (RealClock, "__init__", clock_init), (VirtualClock, "__init__", virtual_clock_init),
        (time, "sleep", timed_sleep), (asyncio, "sleep", loop_sleep),
        (subprocess.Popen, "__init__", popen), (looptime, "new_event_loop", virtual_loop)]
    for owner, name, probe in patches:
        setattr(owner, name, probe)


def pytest_configure(config: pytest.Config) -> None:
    """Install the probes once per (worker) process."""
    _patch()


@pytest.hookimpl(wrapper=True)
def pytest_fixture_setup(fixturedef: pytest.FixtureDef[Any],
                         request: pytest.FixtureRequest) -> Generator[None, Any, Any]:
    """What a fixture's setup did counts for every test that uses it."""
    outer = set(_current)
    _current.clear()
    try:
        return (yield)
    finally:
        _by_fixture[(fixturedef.argname, fixturedef.baseid)] = set(_current)
        _current.update(outer)


def _fixture_reasons(item: pytest.Item) -> set[str]:
    out: set[str] = set()
    for name in getattr(item, "fixturenames", ()):
        keys = [k for k in _by_fixture if k[0] == name and item.nodeid.startswith(k[1])]
        if keys:
            out |= _by_fixture[max(keys, key=lambda k: len(k[1]))]
    return out


@pytest.hookimpl(wrapper=True)
def pytest_runtest_setup(item: pytest.Item) -> Generator[None, None, None]:
    """Collect the setup's reasons."""
    _current.clear()
    try:
        return (yield)
    finally:
        _setup[item.nodeid] = set(_current)


@pytest.hookimpl(wrapper=True)
def pytest_runtest_call(item: pytest.Item) -> Generator[None, None, None]:
    """Collect the call's reasons and write the test's line."""
    _current.clear()
    try:
        return (yield)
    finally:
        reasons = _current | _setup.pop(item.nodeid, set()) | _fixture_reasons(item)
        real = sorted(reasons - {"virtual loop", "virtual clock"})
        kind = "real" if real else "virtual" if reasons else "pure"
        out = os.environ.get("FLEETGATE_REALTIME_SHARE")
        if out:
            with open(out, "a", encoding="utf-8") as f:
                f.write(json.dumps({"test": item.nodeid, "kind": kind, "why": real}) + "\n")
