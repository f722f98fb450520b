"""The random plan generator makes valid 1-robust plans (checked by the planner's validator)."""

from __future__ import annotations

import random

from hypothesis import given, settings
from hypothesis import strategies as st

from gateway.planning.random_plans import open_grid, random_plan
from gateway.planning.validate import plan_violations


@settings(max_examples=60, deadline=None)
@given(st.integers(2, 7), st.integers(2, 7), st.integers(1, 6), st.integers(0, 20),
       st.integers(0, 2**32 - 1))
def test_random_plans_are_valid(w: int, h: int, n: int, steps: int, seed: int) -> None:
    grid = open_grid(w, h)
    n = min(n, w * h)
    plan = random_plan(grid, n, steps, random.Random(seed))
    starts = [p[0] for p in plan.paths]
    goals = [p[-1] for p in plan.paths]
    assert plan_violations(grid, starts, goals, plan) == []
