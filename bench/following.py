"""What the no-following rule costs under the LoRR 2024 rules: PIBT with and without it.

A pure step simulation of the shared random-example_400 under the 2024 rules (one action per
step, no delays, 200 steps, tasks revealed 1.5 x the team, the ``shortest`` scheduler,
unstarted tasks reassigned every step): every step the fleet's next action is planned by
fleetgate's windowed PIBT
(:class:`~gateway.planning.pibt.WindowedPIBT`, one step, priorities kept) from the state the
previous step left, with no planning latency and no committed window. The baseline is
fleetgate's 1-robust PIBT (nobody enters a cell another robot held the step before); the
variant, :class:`FollowingPIBT`, lets a robot move forward into a cell whose robot leaves it in
the same step (the 2024 rules allow that; swaps stay forbidden), everything else the same.
A third run, :class:`GhostPIBT`, is free flow (robots pass through each other): what the
scheduler and the turns allow without any congestion. Each step of the first two is checked
(no two robots on a cell, no swap; the 1-robust run also: nobody enters a cell held the step
before). Turns towards a cell being left are allowed, as the LoRR simulator's planner does under
the 2024 rules (:attr:`~gateway.planning.pibt.WindowedPIBT.turn_to_leaving`). ``--lanes P``:
every planner guided by crisscross lanes of penalty P (:mod:`gateway.planning.guidance`).
Prints one result line: tasks finished per planner seed
by each, and ``ratio`` = following / 1-robust (how much the rule costs, at the same
planner), beside the 2024 winner's 698 tasks.

    nice -n 10 .venv/bin/python bench/following.py --seeds 3
"""

from __future__ import annotations

import fleetgate.userio.script  # noqa: F401 (first: Ctrl-C while importing is one line)

# isort: split

import dataclasses
import json
import statistics
from array import array
from collections.abc import Sequence
from pathlib import Path

from fleetgate.userio.exits import CommandParser, run_main
from gateway.execution.lifelong.errands import ErrandBook, TaskDistances
from gateway.execution.lifelong.tasks import SCHEDULERS, TaskPool
from gateway.planning.guidance import crisscross
from gateway.planning.lorr import LorrProblem, read_problem
from gateway.planning.pibt import (
    MAX_PUSH_DEPTH,
    StateSpace,
    Window,
    WindowedPIBT,
)

SHARED = Path(__file__).resolve().parents[1] / ".." / "shared" / "lorr"
PROBLEM = "random.domain/random-example_400.json"
WINNER = 698
"""Tasks the LoRR 2024 winner (EPIBT) finished on it in 200 steps (issue 28)."""


class FollowingPIBT(WindowedPIBT):
    """:class:`WindowedPIBT` without the 1-robust rule: a robot may move forward into a cell
    whose robot moves out in the same step (asking an undecided one to move first, as PIBT
    does); turns, waits, priorities and costs unchanged; no swaps, no rotations."""

    def _enter_held(self, r: int, o: int, pusher: int, rs: int, cur: list[int],
                    nxt: list[int], tables: list[array[int] | None], depth: int) -> bool:
        """Forward into ``o``'s cell if ``o`` moves out in this step (asked first if it has
        not decided; it may not turn in place then); a turn towards it, or a swap, as
        1-robust."""
        cell_of = self.space.cell_of
        c, c2 = cell_of[cur[r]], cell_of[cur[o]]
        if cell_of[rs] != c2 or o == pusher:
            return super()._enter_held(r, o, pusher, rs, cur, nxt, tables, depth)
        if self._planned[o] != self._stamp:
            if depth >= MAX_PUSH_DEPTH:
                return False
            self._reserved[c2] = self._stamp
            self._decide(o, r, cur, nxt, tables, depth + 1)
        return cell_of[nxt[o]] not in (c2, c)


class GhostPIBT(WindowedPIBT):
    """Free flow: every robot takes its best move as if it were alone on the map (robots
    pass through each other), so the scheduler and the turning cost alone bound the tasks."""

    def plan(self, states: Sequence[int], goals: Sequence[Sequence[int]], steps: int,
             hold: Sequence[int] | None = None, avoid: Sequence[int] = ()) -> Window:
        """``steps`` timesteps of each robot's best moves, alone (``hold``, ``avoid``: none)."""
        space, n = self.space, self.n
        progress = [0] * n
        reached: list[list[int]] = [[] for _ in range(n)]
        cur = list(states)
        for r in range(n):
            self._arrive(r, cur[r], goals[r], progress, reached, 0)
        out = [cur]
        for step in range(1, steps + 1):
            nxt = list(cur)
            for r, g in enumerate(goals):
                if progress[r] < len(g):
                    opts = space.options[cur[r]]
                    costs = space.costs(space.distances(g[progress[r]]), opts)
                    nxt[r] = opts[min(range(len(opts)), key=lambda i: (costs[i], i))][3]
                self._arrive(r, nxt[r], g, progress, reached, step)
            out.append(nxt)
            cur = nxt
        return Window(out, reached)


def check_step(cells: list[int], before: list[int], robust: bool) -> None:
    """Raise if the step from ``before`` to ``cells`` puts two robots on a cell, swaps two, or
    (``robust``) enters a cell another robot held the step before."""
    if len(set(cells)) != len(cells):
        raise SystemExit("two robots on one cell")
    held = {c: r for r, c in enumerate(before)}
    for r, (a, b) in enumerate(zip(before, cells, strict=True)):
        o = held.get(b, r)
        if a != b and o != r:
            if robust:
                raise SystemExit(f"robot {r} entered a cell robot {o} held")
            if cells[o] == a:
                raise SystemExit(f"robots {r} and {o} swapped")


PLANNERS: dict[str, type[WindowedPIBT]] = {"robust": WindowedPIBT,
                                           "following": FollowingPIBT, "ghost": GhostPIBT}


def pure_run(problem: LorrProblem, planner: str, seed: int, steps: int,
             scheduler: str, lanes: int = 0) -> int:
    """Tasks finished in ``steps`` steps of the pure simulation with the planner of
    :data:`PLANNERS` (see the module doc), guided by crisscross ``lanes`` if not 0."""
    n = problem.team_size
    grid = problem.grid
    space = StateSpace(grid, True, robots=n, exact=True if lanes else None,
                       guidance=crisscross(grid, lanes) if lanes else None)
    pibt = PLANNERS[planner](space, n, seed=seed, turn_to_leaving=True)  # as the 2024 rules'
    distances = TaskDistances(grid)
    pool = TaskPool(problem.tasks, max(1, int(problem.num_tasks_reveal * n)),
                    leg=distances.leg)
    book = ErrandBook(pool, n)
    states = [space.state(c) for c in problem.starts]
    for t in range(steps):
        book.release_unstarted(t)  # as the lifelong runs reassign at every call
        book.schedule([space.cell_of[s] for s in states], SCHEDULERS[scheduler], distances, t)
        win = pibt.plan(states, book.goals(), 1)
        tasks_of = book.planned(win.reached)
        for r, hits in enumerate(win.reached):
            for _ in hits:
                pool.errand_done(tasks_of[r], t)
        if planner != "ghost":
            check_step([space.cell_of[s] for s in win.states[1]],
                       [space.cell_of[s] for s in states], planner == "robust")
        states = win.states[1]
    return pool.finished


def main() -> None:
    """Run both planners over the planner seeds and print one result line."""
    ap = CommandParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=3, help="planner seeds (tie-breaks)")
    ap.add_argument("--steps", type=int, default=200)
    ap.add_argument("--scheduler", choices=sorted(SCHEDULERS), default="shortest")
    ap.add_argument("--lanes", type=int, default=0, metavar="PENALTY",
                    help="guide the planners by crisscross lanes (gateway/planning/guidance.py; "
                         "default 0: none)")
    ap.add_argument("--lorr", type=Path, default=SHARED,
                    help="the shared LoRR problems (default ../shared/lorr beside the repo)")
    ap.add_argument("--json", action="store_true", help="print one JSON line")
    args = ap.parse_args()
    if args.seeds < 1 or args.steps < 1:
        ap.error("--seeds and --steps must be at least 1")
    if args.lanes < 0:
        ap.error("--lanes must be at least 0")
    blocking = next((q for q in (args.lorr, *args.lorr.parents) if q.exists()), None)
    if blocking is not None and not blocking.is_dir():
        ap.error(f"--lorr: {blocking} is not a folder")
    if not (args.lorr / PROBLEM).is_file():
        print(json.dumps({"skipped": f"{args.lorr / PROBLEM} absent"}) if args.json
              else f"following: skipped ({args.lorr / PROBLEM} absent)")
        return
    problem = read_problem(args.lorr / PROBLEM)
    problem = dataclasses.replace(problem, agent_counter=1,
                                  delay=dataclasses.replace(problem.delay, p_delay=0.0))
    runs = {name: [pure_run(problem, name, s, args.steps, args.scheduler, args.lanes)
                   for s in range(args.seeds)] for name in PLANNERS}
    mean = {name: statistics.mean(got) for name, got in runs.items()}
    out: dict[str, object] = {
        "steps": args.steps, "scheduler": args.scheduler, "lanes": args.lanes, **runs,
        "ratio": round(mean["following"] / mean["robust"], 3) if mean["robust"] else None,
        **{f"{name}_vs_winner": round(m / WINNER, 3) for name, m in mean.items()}}
    print(json.dumps(out) if args.json else
          f"following: random-400 under the 2024 rules, {args.steps} steps, pure PIBT "
          f"simulation, lanes {args.lanes}: 1-robust {runs['robust']} tasks, following allowed "
          f"{runs['following']}: ratio {out['ratio']}; free flow (robots pass through each "
          f"other) {runs['ghost']}; vs the 2024 winner's {WINNER}: "
          f"{out['robust_vs_winner']}, {out['following_vs_winner']}, "
          f"{out['ghost_vs_winner']}; every step checked")

if __name__ == "__main__":
    run_main("bench/following.py", main)
