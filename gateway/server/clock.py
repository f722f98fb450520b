"""Time for the gateway: real time, or virtual time for a whole asyncio system.

Both clocks read the running event loop's clock, so everything that sleeps on the loop (the
gateway's ticks, simulated robots, timeouts) shares one notion of time. Virtual time comes
from a ``looptime`` event loop (:func:`run_virtual`): when every task is waiting, the loop
jumps to the next timer instead of sleeping. We use that library rather than hand-writing
time travel because detecting "all tasks idle" needs the loop's internals (its selector and
timer heap), which looptime already patches and tests; a clock object alone cannot know it.

The two clocks differ in how they run the planner: :class:`RealClock` runs it in a thread
(events keep arriving while it works); :class:`VirtualClock` runs it inline, so virtual time
stands still while it computes, and then charges its time as configured ("measured": the
solver's CPU time, "zero", or a fixed number of ms; DESIGN section 2) by sleeping that long in
virtual time. ``run_measured`` is the same for a planner that runs in another process and
reports its own CPU time (the lifelong planner process): a thread waits for it in real time;
under virtual time the loop waits for it inline and charges the CPU time it reported.
Plan time can run ``speed`` times faster than the loop clock (the demo's ``--speed``).
:func:`run_paced` is virtual time held back to the wall clock: what runs in the loop sees
exactly the times of a virtual run, whatever the machine's load, and a person watching sees it
at the wall clock's pace (slower, never faster, when the process is starved of CPU).
"""

from __future__ import annotations

import asyncio
import time
from collections.abc import Callable, Coroutine
from typing import Any, TypeVar

from gateway.runtime.solver_time import SolverTime, charge_ms, run_charged

T = TypeVar("T")


class LoopClock:
    """Milliseconds of plan time since :meth:`reset`, read from the running loop's clock."""

    def __init__(self, speed: float = 1.0) -> None:
        self._speed = float(speed)
        self._base_loop_s: float | None = None
        self._base_ms = 0.0

    @staticmethod
    def _loop_s() -> float:
        return asyncio.get_running_loop().time()

    def reset(self, at_ms: float = 0.0) -> None:
        """Make now ``at_ms`` (0 when the gateway or a run starts; a resumed run's time)."""
        self._base_loop_s = self._loop_s()
        self._base_ms = at_ms

    @property
    def speed(self) -> float:
        """How many ms of plan time pass per ms of loop time."""
        return self._speed

    def set_speed(self, speed: float) -> None:
        """Change the speed from now on; ``now_ms`` stays continuous."""
        if speed <= 0:
            raise ValueError(f"speed must be positive, got {speed}")
        self._base_ms = self.now_ms()
        self._base_loop_s = self._loop_s()
        self._speed = float(speed)

    def now_ms(self) -> float:
        """Plan time in ms since :meth:`reset` (resets on first use)."""
        if self._base_loop_s is None:
            self.reset()
        assert self._base_loop_s is not None
        return self._base_ms + (self._loop_s() - self._base_loop_s) * 1000.0 * self._speed

    async def sleep_until_ms(self, t_ms: float) -> None:
        """Sleep until plan time ``t_ms`` (returns at once if it has passed)."""
        delay = (t_ms - self.now_ms()) / self._speed / 1000.0
        await asyncio.sleep(max(0.0, delay))

    async def settle(self) -> None:
        """Let the work of the current instant finish before a tick (no-op in real time)."""

    def wall_s(self) -> float:
        """Seconds since the epoch, on this clock (a run's start, and how long a stopped
        gateway was away when it resumes)."""
        return time.time()

    async def wait_for(self, fn: Callable[[], T]) -> T:
        """Wait for ``fn`` (blocking work done elsewhere, e.g. a process starting) off the
        loop, so that events keep arriving meanwhile."""
        return await asyncio.to_thread(fn)


class RealClock(LoopClock):
    """Wall-clock time; the planner runs in a worker thread."""

    async def run_solver(self, fn: Callable[[], T]) -> tuple[T, float]:
        """Run ``fn`` off the loop; returns its result and the wall ms it took."""
        t0 = time.perf_counter()
        result = await asyncio.to_thread(fn)
        return result, (time.perf_counter() - t0) * 1000.0

    async def run_measured(self, fn: Callable[[], tuple[T, float]]) -> tuple[T, float]:
        """Wait off the loop for ``fn`` (work done elsewhere: its result and its CPU ms);
        returns the result and the wall ms it took."""
        t0 = time.perf_counter()
        result, _cpu_ms = await asyncio.to_thread(fn)
        return result, (time.perf_counter() - t0) * 1000.0


class VirtualClock(LoopClock):
    """Virtual time; needs a looptime loop (:func:`run_virtual`).

    ``solver_time`` says how much virtual time a planner call costs.
    """

    EPOCH_S = 1_767_225_600.0
    """The wall time of loop time 0 (2026-01-01 UTC): virtual runs are reproducible."""

    SETTLE_ROUNDS = 64
    """Loop iterations a tick waits so that same-instant messages (several hops) arrive."""

    def __init__(self, speed: float = 1.0, solver_time: SolverTime = "zero") -> None:
        super().__init__(speed)
        self.solver_time = solver_time

    def reset(self, at_ms: float = 0.0) -> None:
        """Make now ``at_ms``; refuses to run on a loop without virtual time."""
        import looptime  # imported here: it pulls in pytest, ~0.5 s at every CLI start

        loop = asyncio.get_running_loop()
        if not isinstance(loop, looptime.LoopTimeEventLoop) or not loop.looptime_on:
            raise RuntimeError("VirtualClock needs a looptime event loop: use run_virtual()")
        super().reset(at_ms)

    def now_ms(self) -> float:
        """Plan time, rounded to the loop's resolution (1 µs) so that integral instants are
        exact (1.001 s x 1000 is not 1001.0 in floating point)."""
        return round(super().now_ms(), 3)

    async def settle(self) -> None:
        """Yield enough loop iterations for every same-instant hop to complete."""
        for _ in range(self.SETTLE_ROUNDS):
            await asyncio.sleep(0)

    def wall_s(self) -> float:
        """Virtual wall time: :attr:`EPOCH_S` plus the loop's virtual seconds (a gateway
        resumed in the same loop sees the virtual time it was away, whatever the real time)."""
        return self.EPOCH_S + self._loop_s()

    async def wait_for(self, fn: Callable[[], T]) -> T:
        """Wait for ``fn`` inline: virtual time stands still meanwhile."""
        return fn()

    async def run_solver(self, fn: Callable[[], T]) -> tuple[T, float]:
        """Run ``fn`` inline (virtual time stands still), then sleep the charged time."""
        result, charge = run_charged(fn, self.solver_time)
        await self.sleep_until_ms(self.now_ms() + charge)
        return result, charge

    async def run_measured(self, fn: Callable[[], tuple[T, float]]) -> tuple[T, float]:
        """Wait for ``fn`` (work done elsewhere: its result and its CPU ms) inline, so virtual
        time stands still, then sleep what its CPU ms charge."""
        result, cpu_ms = fn()
        charge = charge_ms(cpu_ms, self.solver_time)
        await self.sleep_until_ms(self.now_ms() + charge)
        return result, charge


Clock = RealClock | VirtualClock
"""Either clock; both share the :class:`LoopClock` interface plus ``run_solver``."""


def run_virtual(main: Coroutine[Any, Any, T]) -> T:
    """Run ``main`` to completion on a fresh event loop in virtual time (starting at 0 s)."""
    import looptime

    with asyncio.Runner(loop_factory=lambda: looptime.new_event_loop(start=0.0)) as runner:
        return runner.run(main)


PACE_PERIOD_S = 0.01
"""How often (loop time) :func:`run_paced` holds virtual time back to the wall clock."""


async def _pace() -> None:
    """Keep the loop's virtual time from running ahead of the wall clock: each
    :data:`PACE_PERIOD_S` of loop time lasts at least as long on the wall clock (the loop is
    blocked for the rest: virtual time cannot move meanwhile). A period the starved process
    took longer for is not made up by running faster later."""
    while True:
        wall_0 = time.monotonic()
        await asyncio.sleep(PACE_PERIOD_S)
        rest = PACE_PERIOD_S - (time.monotonic() - wall_0)
        if rest > 0:
            time.sleep(rest)


def run_paced(main: Coroutine[Any, Any, T]) -> T:
    """Run ``main`` like :func:`run_virtual`, its virtual time paced by the wall clock."""

    async def paced() -> T:
        pacer = asyncio.ensure_future(_pace())
        try:
            return await main
        finally:
            pacer.cancel()
            await asyncio.gather(pacer, return_exceptions=True)

    return run_virtual(paced())
