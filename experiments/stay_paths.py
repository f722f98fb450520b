"""The stay bound for policies that decide more than once (:mod:`experiments.stay_bound`).

A policy that does not know the stay sees, while the block lasts, only that it has not ended;
so whatever it decides is a fixed *path* of decisions, the same for every stay that outlasts
them: keep the plan, or at a time ``t`` (every ``step_ms`` from the block's first report, the
earliest an online policy knows the cell) switch to a plan solved for an assumed stay ``a``
(the intruder's cell free from the robot's need plus ``a``), and, later while the block
still lasts, switch once more to a plan that assumes a longer stay. When the block ends (at
``need + stay``) the policy is granted the end at once and the better of keeping its plan
and replanning back (a replan without the obstacle, at the first moment the fleet runs),
outcomes it is granted too: with the stay known, the rest of a run is deterministic.

For each equally likely stay of the grid the table holds every path's saving against not
replanning; a path whose next decision comes after the block ended saves what its prefix
saves (the policy never took it). A Bayes-optimal policy of this family -- the dynamic
programme over (how long the block has lasted, the plan it follows) given the stay's
distribution -- picks per experiment the path with the best expected saving; with a budget on
the share of experiments worse than not replanning, :func:`experiments.stay_bound.
choose_capture` solves the campaign's linear program over the paths. The policy knows every
path's outcome at every stay: more than a real policy knows, so the optimum bounds the
family from above (within the grids of times, assumed stays and stays).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

from experiments.oracle import ExperimentKey, Memo
from experiments.stay_bound import Assumed, Options, choose_capture
from gateway.execution.commands import SolveRequest
from gateway.execution.oneshot.executor import Mode
from gateway.planning.plan import Plan
from sim_clients.des import SimConfig, Simulation
from sim_clients.intruder import IntruderState
from sim_clients.stays import StaySpec

Path = tuple[tuple[float, float], ...]
"""The switches a policy makes while the block lasts: ``(time ms, assumed stay s)``."""

TICK_MS = 100.0
"""The executor's tick: a decision that finds the fleet stopping waits for the next."""


class _Paths(Assumed):
    """A fork that may switch several times; once the intruder is gone, its replan knows it
    (no obstacle: the replan back); ``branching``: it is forked again later, so it must
    simulate its own run instead of reading the memo's continuation."""

    branching = False

    def plan_for(self, request: SolveRequest, now: float) -> tuple[Plan | None, float]:
        intr = self.intruder
        if intr is not None and intr.state is IntruderState.GONE and request.obstacles:
            request = dataclasses.replace(request, obstacles=(), start_ms=None)
        return super().plan_for(request, now)

    def solved(self, now: float) -> None:
        if self.branching:
            self.state_key = None
            Simulation.solved(self, now)
            return
        super().solved(now)


def _switch(sim: _Paths, at: float, assumed_s: float | None, memo: Memo,
            branching: bool) -> _Paths | None:
    """A fork of ``sim`` (run to ``at``) that replans at ``at`` assuming ``assumed_s`` (None:
    the replan back, the intruder gone); None if the fleet is not running then."""
    sim.run_until(at)
    if sim.finished() or sim.executor.mode is not Mode.RUNNING \
            or sim.executor.replans >= sim.executor.max_replans:
        return None
    fork = sim.fork(share=(memo,))
    fork.branching = branching
    fork.assumed_ms = None if assumed_s is None else 1000.0 * assumed_s
    fork.replan_now(at)
    return fork


def _settle(sim: _Paths, end_ms: float, memo: Memo) -> float:
    """The SOC of the better of keeping ``sim``'s plan and replanning back once the block
    has ended at ``end_ms`` (at the first tick the fleet runs, within ten seconds)."""
    t = end_ms
    back: float | None = None
    while t <= end_ms + 10_000.0:
        sim.run_until(t)
        if sim.finished():
            break
        fork = _switch(sim, t, None, memo, False)
        if fork is not None:
            fork.run_until(None)
            back = fork.outcome()[0]
            break
        t += TICK_MS
    sim.run_until(None)
    keep = sim.outcome()[0]
    return keep if back is None else min(keep, back)


@dataclass(frozen=True)
class PathTable:
    """One experiment's savings (ms, against not replanning) of every path at each stay."""

    key: ExperimentKey
    need_ms: float
    """The block's first report (when the robot needed the cell)."""
    clairvoyant: tuple[float, ...]
    """The clairvoyant's saving (one informed replan knowing the stay, from ``T_a``)."""
    paths: dict[Path, tuple[float, ...]]
    """Every path (the empty one: keep, then settle at the end) -> saving per stay."""

    def to_json(self) -> dict[str, Any]:
        """A JSON-able form (one line of the bench's output file)."""
        return {"key": list(self.key), "need_ms": self.need_ms,
                "clairvoyant": list(self.clairvoyant),
                "paths": [[[list(s) for s in p], list(g)] for p, g in self.paths.items()]}

    @staticmethod
    def from_json(row: dict[str, Any]) -> PathTable:
        """The table of one line of the bench's output file (:meth:`to_json`)."""
        m, n, i, seed = row["key"]
        return PathTable((str(m), int(n), int(i), int(seed)), float(row["need_ms"]),
                         tuple(row["clairvoyant"]),
                         {tuple((float(t), float(a)) for t, a in p): tuple(g)
                          for p, g in row["paths"]})

    def options(self) -> Options:
        """The expected saving and worse-than-none chance of each path (for
        :func:`choose_capture`)."""
        n = len(self.clairvoyant)
        return [(sum(g) / n, sum(1 for x in g if x < 0) / n) for g in self.paths.values()]


def path_table(config: SimConfig, key: ExperimentKey, stays_s: Sequence[float],
               assumed_s: Sequence[float], clairvoyant: Sequence[float],
               step_ms: float = 1000.0, second_step_ms: float = 2000.0,
               switches: int = 2) -> PathTable:
    """The path table of one experiment (``config``: its intruder variant, any stay; the
    clairvoyant's savings per stay from :func:`experiments.stay_bound.gain_table`): first
    switches every ``step_ms`` from the block's first report, second ones every
    ``second_step_ms`` after the first, to a longer assumed stay (``switches`` is 1 or 2)."""
    if switches not in (1, 2):
        raise ValueError(f"switches must be 1 or 2, got {switches}")
    memo = Memo()
    rows: list[dict[Path, float]] = []
    need = 0.0
    for stay in stays_s:
        cfg = dataclasses.replace(config, policy="none", max_replans=switches + 1,
                                  informed=True, intruder_stay=StaySpec("fixed", (stay,)))
        base = _Paths(cfg, memo)
        base.branching = True
        base.start()
        appear = cfg.intruder_config.appear_ms
        base.run_until(appear)
        intr = base.intruder
        while intr is not None and intr.state is IntruderState.ABSENT and not base.finished():
            base.run_until(base.now + TICK_MS)  # until the intruder has appeared
        none_fork = base.fork(share=(memo,))
        none_fork.branching = False
        none_fork.run_until(None)
        none = none_fork.outcome()[0]
        got: dict[Path, float] = {(): 0.0}
        rows.append(got)
        if intr is None or intr.cell is None or intr.config.stay_ms is None:
            continue  # the intruder blocks nobody: nothing to decide
        need = intr.leave_ms - intr.config.stay_ms
        end = intr.leave_ms
        got[()] = none - _settle(base.fork(share=(memo,)), end, memo)
        t1 = appear + step_ms * max(0.0, -(-(need - appear) // step_ms))
        while t1 < end:
            base.run_until(t1)
            for a1 in assumed_s:
                f1 = _switch(base, t1, a1, memo, True)
                if f1 is None:
                    continue
                t2 = t1 + second_step_ms
                while switches == 2 and t2 < end:
                    for a2 in (a for a in assumed_s if a > a1):
                        f2 = _switch(f1, t2, a2, memo, False)
                        if f2 is not None:
                            got[((t1, a1), (t2, a2))] = none - _settle(f2, end, memo)
                    t2 += second_step_ms
                got[((t1, a1),)] = none - _settle(f1, end, memo)
            t1 += step_ms
    every = sorted({p for got in rows for p in got}, key=lambda p: (len(p), p))
    paths = {p: tuple(_saving(got, p) for got in rows) for p in every}
    return PathTable(key, need, tuple(clairvoyant), paths)


def _saving(got: dict[Path, float], path: Path) -> float:
    """A path's saving at one stay: its own, or its longest prefix's whose decisions all came
    while the block lasted (a decision the fleet could not take is kept as not taken)."""
    while path not in got:
        path = path[:-1]
    return got[path]


def best_path_capture(tables: Sequence[PathTable], budget: float,
                      max_switches: int = 2) -> tuple[float, float, float | None]:
    """The pooled capture, expected worse-than-none share and median capture of the best
    paths of at most ``max_switches`` switches (see the module's docstring)."""
    options = [[o for p, o in zip(t.paths, t.options(), strict=True) if len(p) <= max_switches]
               for t in tables]
    clair = [sum(t.clairvoyant) / len(t.clairvoyant) for t in tables]
    return choose_capture(options, clair, budget)
