"""A pause across the execution core: the monitor stays true while the fleet stands still,
no policy fires during it, and the waiting the pause itself caused is not slack growth
afterwards (a block that cleared during the pause triggers no replan on resume).

The corridor of Fig. 4: robot 0 drives (1,0) -> (5,0), robot 1 waits one step at (0,0) and
follows, so robot 1's a_1 waits for robot 0's a_0 (a Type 2 edge). With robot 0 blocked on
a_0 and robot 1's wait done at 1000 ms, δ of that edge is t_c(a_0^0) - 1000 = now + 1000 -
1000 = now (it was 0 in the plan): the fleet slack Δ̄F equals the present, to the tick.
"""

from __future__ import annotations

import pytest

from gateway.execution.commands import Trigger
from gateway.execution.oneshot.executor import MONITOR_PERIOD_MS, ExecutionError, Executor
from gateway.execution.oneshot.policies import SlackReplan
from gateway.planning.plan import Plan
from tests.execution.test_adg import CORRIDOR

THRESHOLD_MS = 2000.0


def _blocked_corridor() -> Executor:
    """Robot 0 blocked on a_0 from time 0; robot 1's wait a_0 runs 0..1000."""
    ex = Executor(Plan.of(CORRIDOR), policy=SlackReplan(THRESHOLD_MS))
    ex.start(0)
    ex.blocked(0, 0, 0, 0)
    ex.started(1, 0, 0, 0)
    ex.finished(1, 0, 0, 1000)
    ex.drain()
    return ex


def _tick_until(ex: Executor, begin: int, end: int) -> list[tuple[int, float]]:
    """Tick every monitor period in [begin, end]; (time, fleet slack) at each, stopping at
    the first trigger."""
    seen = []
    for t in range(begin, end + 1, MONITOR_PERIOD_MS):
        ex.tick(t)
        seen.append((t, ex.monitor.fleet_slack()))
        if any(isinstance(c, Trigger) for c in ex.drain()):
            return seen
    return seen


def test_without_a_pause_the_block_triggers_a_replan() -> None:
    ex = _blocked_corridor()
    seen = _tick_until(ex, 1100, 6000)
    assert seen[-1] == (2100, 2100.0)  # the first tick past 2000 ms of slack growth
    assert ex.replans == 1


def test_a_block_that_clears_during_the_pause_triggers_no_replan() -> None:
    ex = _blocked_corridor()
    assert _tick_until(ex, 1100, 1500)[-1] == (1500, 1500.0)
    ex.pause(1500)
    during = _tick_until(ex, 1600, 3000)
    ex.unblocked(0, 0, 0, 3000)  # the intruder left; robot 0 stands still until the resume
    during += _tick_until(ex, 3100, 5000)
    # the monitor stays true while paused (robot 0 is late, and later every tick) ...
    assert during[-1] == (5000, 5000.0) and ex.replans == 0
    ex.resume(5000)
    # ... and after the pause only what happens next counts: 1500 ms as before the pause
    assert ex.monitor.fleet_slack() == 1500.0
    ex.started(0, 0, 0, 5000)
    after = _tick_until(ex, 5100, 5900)  # robot 0 is moving on time: nothing changes
    assert after == [(t, 1500.0) for t in range(5100, 6000, MONITOR_PERIOD_MS)]
    assert ex.replans == 0


def test_a_block_that_outlasts_the_pause_still_triggers() -> None:
    ex = _blocked_corridor()
    _tick_until(ex, 1100, 1500)
    ex.pause(1500)
    _tick_until(ex, 1600, 5000)
    ex.resume(5000)
    seen = _tick_until(ex, 5100, 9000)
    # 1500 ms before the pause, and 500 ms more after it (the tick at 5600)
    assert seen[-1] == (5600, 2100.0) and ex.replans == 1


def test_pause_and_resume_must_alternate() -> None:
    ex = _blocked_corridor()
    with pytest.raises(ExecutionError, match="not paused"):
        ex.resume(1100)
    ex.pause(1100)
    with pytest.raises(ExecutionError, match="already paused"):
        ex.pause(1200)
