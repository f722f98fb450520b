"""bench/crash.py in the suite: the gateway as its own process, killed with SIGKILL twice
mid-run and restarted with the same command line, resumes and loses nothing."""

from __future__ import annotations

from bench.crash import run


def test_a_gateway_killed_twice_resumes_and_nothing_is_lost_or_doubled() -> None:
    result = run(kills=2, seed=3, robots=4, steps=12, speed=10.0, per_run=2)
    assert result["kills"] == 2
    assert result["resumed"] == 2
    assert result["completed"] == 1  # the disturbed run completed
    assert result["baseline_lost"] == 0
    assert (result["lost"], result["duplicated"]) == (0, 0)
    assert (result["collisions"], result["trace_errors"], result["robot_errors"]) == (0, 0, 0)
    assert result["soc_ratio"] >= 1.0  # the robots waited for the restarts
