"""Lifelong operation: throughput on the LoRR problems, and simulation speed at 1,000 robots.

Part 1 (skipped cleanly if ``../shared/lorr`` is absent): each of the four shared LoRR
problems for ``--ticks`` ticks under its rules (delays from its ``delayConfig``, 1000 ms
planning period at 100 ms a tick, the planner's measured CPU time charged), tasks finished
against the LoRR Start-Kit's reference in ``SOURCES.md`` (one ratio per problem), and the
output replayed by the independent checker (``tracecheck/lorr.py``): collisions
must be 0. ``--delay-seeds K`` runs each problem with K delay seeds (the file's and the next
ones; the reference was measured with the file's) and reports the mean and the smallest ratio,
so a lead is not the luck of one seed; each scheduler of ``--schedulers`` (default all) is run.
``--rules-2024`` adds random-example_400 under the LoRR 2024 rules (one tick per action, no
delays, 200 steps) against the 2024 winner's 698 tasks, with as many planner seeds as delay
seeds (mean and min: without delays a single run is the luck of its tie-breaks). ``--json``:
this part only, as one JSON line (per problem and scheduler: tasks finished per seed, mean,
min, the reference, the ratios, planner CPU seconds per run and the longest call, the longest
assignment wait, ``valid``).

    nice -n 10 .venv/bin/python bench/lifelong.py --json --delay-seeds 3 --rules-2024

``--only-2024``: that row alone (the four problems skipped).

Part 2: ``--robots`` robots for 600 simulated seconds (one action a second, a plan every
second) on a generated warehouse of about 10,000 free cells (shelf rows, like MovingAI's
warehouse-10-20-10-2-1), in CPU seconds; the goal is 60 s on 2 cores, and LSMART (2026, the
same ADG execution) takes 268 s on 16 cores. Prints one result line.

``--journal`` (instead): the shift journal's size and restart time, compacted against not.
A ``--robots`` shift on a generated warehouse runs ``--seconds`` of plan time in virtual time
(:mod:`sim_clients.shift_des`: jittered actions, random stops, planner latency) through the
gateway's journaled executor into two real journals: one never compacted (as before
compaction existed), one compacted into a snapshot every ``--every`` segments as the gateway
does. Each is then read back and replayed into a fresh executor (what a restart does before
it serves), which must equal the live shift. Prints one line: records, bytes and replay CPU
seconds of both, ``replay_ratio`` (compacted / uncompacted replay time), and the wall time of
a compaction (median and longest: the first one writes the task history kept so far, the
later ones only what is new). ``--kept N`` starts the task book with N ended tasks and their
events, as after hours of a shift (the pool keeps 100,000 of each).

    .venv/bin/python bench/lifelong.py --journal --robots 100 --seconds 3600 --json

``--scale`` (instead): the LoRR archive's warehouse_large (10,000 robots) and brc202d (6,500)
under the 2026 rules, ``--ticks`` ticks each (skipped when the archive copy is absent), and
a generated 10,000-robot warehouse of 1,000,000 cells (``--scale-only`` picks some;
:mod:`sim_clients.lifelong_scale`), with at most ``--station-cap`` robots sent to one
first-errand cell at a time (default 4; 0: no bound).

    .venv/bin/python bench/lifelong.py --scale --archive DIR --ticks 600
"""

from __future__ import annotations

import fleetgate.userio.script  # noqa: F401 (first: Ctrl-C while importing is one line)

# isort: split

import argparse
import copy
import dataclasses
import json
import statistics
import sys
import tempfile
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from fleetgate.userio.exits import CommandParser, run_main
from gateway.execution.lifelong.executor import LifelongExecutor
from gateway.execution.lifelong.shift_state import HistoryLog, snapshot_shift
from gateway.execution.lifelong.tasks import (
    SCHEDULERS,
    NewTask,
    TaskEvent,
    TaskPool,
    wait_percentiles,
)
from gateway.planning.lorr import LorrProblem, read_problem, warehouse_problem
from gateway.planning.movingai import format_map
from gateway.runtime.journal import Journal, JournalRecord, ShiftRecord
from gateway.server.gc_tuning import restore_defaults, tune_for_run
from gateway.server.runs.shift_journal import (
    JournaledLifelong,
    compact_journal,
    compaction_due,
    replay_shift,
)
from gateway.server.runs.task_journal import TaskJournal
from sim_clients.lifelong import LANES, LifelongConfig, lorr_output, run_lifelong
from sim_clients.lifelong_scale import (
    ARCHIVE_ENV,
    INSTANCES,
    MILLION,
    STATION_CAP,
    archive_dir,
    scale_line,
    scale_one,
    scale_runs,
)
from sim_clients.shift_des import drive_shift
from tracecheck.lorr import check_output, read_free

REPO = Path(__file__).resolve().parents[1]

SHARED = REPO / ".." / "shared" / "lorr"
REFERENCE = {  # tasks finished in 600 ticks by the Start-Kit's default planner + executor
    "maze": ("maze.domain/maze-example_40.json", 55),
    "room": ("room.domain/room-example_150.json", 107),
    "random": ("random.domain/random-example_400.json", 409),
    "city": ("city.domain/bos-example_600.json", 39),
}


RULES_2024 = ("random", 698)
"""The 2024-rules conversion of random-example_400 (one tick per action, no delays, 200
steps) and the tasks the LoRR 2024 winner (EPIBT) finished on it, built and run here under
those rules (issue 28)."""


def shared_run(problem: LorrProblem, ticks: int, scheduler: str, seed: int = 0
               ) -> dict[str, Any]:
    """One run of ``problem`` (``seed``: the planner's): tasks finished, planner CPU (total and
    longest call) and the assignment waits, its output checked by the independent checker."""
    cfg = LifelongConfig(problem, ticks=ticks, scheduler=scheduler, seed=seed)
    res = run_lifelong(cfg)
    check_output(lorr_output(cfg, res), read_free(format_map(problem.grid)))
    return {"finished": res.finished, "cpu_s": round(sum(res.planner_times), 2),
            "max_call_s": round(max(res.planner_times, default=0.0), 3),
            "wait_max": wait_percentiles(res.waits)["max"]}


def shared_runs(shared: Path, ticks: int, seeds: int, schedulers: Sequence[str]
                ) -> list[dict[str, Any]]:
    """Each shared problem under each scheduler over ``seeds`` delay seeds (the file's, then
    the next ones): tasks finished per seed, mean and min, the Start-Kit reference scaled to
    ``ticks``, the ratios, planner CPU; every output checked (``valid``)."""
    out = []
    for name, (rel, reference) in REFERENCE.items():
        problem = read_problem(shared / rel)
        scaled = reference * ticks / 600
        for scheduler in schedulers:
            runs = []
            for k in range(seeds):
                delay = dataclasses.replace(problem.delay, seed=problem.delay.seed + k)
                runs.append(shared_run(dataclasses.replace(problem, delay=delay), ticks,
                                       scheduler))
            finished = [r["finished"] for r in runs]
            avg = sum(finished) / seeds
            out.append({"problem": name, "scheduler": scheduler, "finished": finished,
                        "mean": round(avg, 1), "min": min(finished),
                        "reference": round(scaled, 1), "ratio": round(avg / scaled, 3),
                        "min_ratio": round(min(finished) / scaled, 3),
                        "cpu_s": [r["cpu_s"] for r in runs],
                        "max_call_s": max(r["max_call_s"] for r in runs),
                        "wait_max_ticks": max(r["wait_max"] for r in runs), "valid": True})
    return out


def rules_2024_run(shared: Path, scheduler: str, seeds: int) -> dict[str, Any]:
    """random-example_400 under the LoRR 2024 rules (one tick per action, no delays, 200
    steps; fleetgate keeps its own no-following safety; the planner guided by crisscross
    lanes, :data:`~sim_clients.lifelong.LANES`) against the 2024 winner's tasks, with
    ``seeds`` planner seeds (without delays one run is the luck of its tie-breaks and of one
    tick of first-call latency: 416 to 456 tasks over five seeds): tasks per seed, mean, min
    and their ratios."""
    name, winner = RULES_2024
    problem = read_problem(shared / REFERENCE[name][0])
    problem = dataclasses.replace(problem, agent_counter=1,
                                  delay=dataclasses.replace(problem.delay, p_delay=0.0))
    runs = [shared_run(problem, 200, scheduler, seed) for seed in range(seeds)]
    finished = [r["finished"] for r in runs]
    avg = sum(finished) / seeds
    return {"problem": f"{name} (2024 rules, 200 steps)", "scheduler": scheduler,
            "lanes": LANES,
            "finished": finished, "mean": round(avg, 1), "min": min(finished),
            "winner": winner, "ratio": round(avg / winner, 3),
            "min_ratio": round(min(finished) / winner, 3),
            "cpu_s": [r["cpu_s"] for r in runs], "valid": True}


def speed_run(robots: int, seconds: int, seed: int) -> tuple[float, int, int]:
    """CPU seconds, tasks finished and free cells of the warehouse run."""
    problem = warehouse_problem(robots, seed)
    cfg = LifelongConfig(problem, ticks=seconds, period=1, tick_ms=1000.0, seed=seed)
    t0 = time.process_time()
    res = run_lifelong(cfg)
    cpu = time.process_time() - t0
    check_output(lorr_output(cfg, res), read_free(format_map(problem.grid)))
    return cpu, res.finished, int(problem.grid.free.sum())


@dataclasses.dataclass
class JournaledShift:
    """A shift driven in virtual time into journals (see :func:`journaled_shift`)."""

    live: LifelongExecutor
    fresh: Callable[[], JournaledLifelong]
    """A new executor of the shift's configuration (to replay a journal into)."""
    before_compaction: list[int]
    """Records of the first compacted journal right before each of its compactions."""
    compact_ms: list[float]
    """Wall ms of each of its compactions (snapshot, encoding, the transaction)."""


def journaled_shift(prob: LorrProblem, seed: int, seconds: float,
                    journals: Sequence[tuple[Journal, int]],
                    each: Callable[[LifelongExecutor, float], None] | None = None,
                    kept: int = 0) -> JournaledShift:
    """Drive ``prob``'s shift for ``seconds`` of plan time (``each``: as in
    :func:`~sim_clients.shift_des.drive_shift`; the pool starts with ``kept`` ended tasks,
    :func:`keep_ended`), journaling its inputs (and task events) into each journal; one with
    ``every`` > 0 is compacted every ``every`` adopted segments as the gateway does (commit,
    then one snapshot replaces the records). Commits happen when plan time moves on (the
    gateway commits before its owner task yields)."""
    start = ShiftRecord(run_id="bench", wall_start_s=0.0, speed=1.0)
    made: list[tuple[tuple[Any, ...], dict[str, Any]]] = []
    tasks: list[TaskJournal] = []
    histories = [HistoryLog() for _ in journals]
    before: list[int] = []
    compact_ms: list[float] = []

    def executor(*args: Any, **kw: Any) -> LifelongExecutor:
        keep_ended(args[3], kept)
        made.append((copy.deepcopy(args), {**kw, "record": None}))
        ex = JournaledLifelong(*args, **kw)
        # the pool's events so far come with the configuration (a fresh copy has them)
        tasks.extend(TaskJournal(ex.pool, j, ex.pool.event_seq) for j, _ in journals)

        def sink(rec: JournalRecord) -> None:
            for tj in tasks:
                tj.flush()
                tj.journal.append(rec)

        ex.sink = sink
        sink(start)
        return ex

    last = {"t": -1.0, "segments": 0}

    def routed(ex: LifelongExecutor, t: float) -> None:
        if t != last["t"]:
            last["t"] = t
            for tj in tasks:
                tj.flush()
                tj.journal.commit()
        if ex.segments == last["segments"]:
            return
        last["segments"] = ex.segments
        for tj, history, (journal, every) in zip(tasks, histories, journals, strict=True):
            if compaction_due(ex, every):
                tj.flush()
                journal.commit()
                first = journal is journals[0][0]
                if first:
                    before.append(journal.count())
                t0 = time.perf_counter()
                compact_journal(journal, history, ex, shift=start, speed=1.0,
                                threshold_ms=0.0, replan_marks=[], trace_lines=0)
                if first:
                    compact_ms.append((time.perf_counter() - t0) * 1000.0)

    run = drive_shift(prob, seed, horizon_ms=seconds * 1000.0, trace=False,
                      executor=executor, each=each, routed=routed)
    for tj in tasks:
        tj.flush()
        tj.journal.commit()
    args, kw = made[0]
    return JournaledShift(run.ex, lambda: JournaledLifelong(*copy.deepcopy(args), **kw),
                          before, compact_ms)


def keep_ended(pool: TaskPool, n: int) -> None:
    """Give ``pool`` ``n`` finished tasks with their events (at most its ``keep`` stay), as a
    shift that ran for hours keeps for the task API. They change no scheduling (schedulers
    look at open tasks only): only what the book holds and a snapshot carries."""
    for k in range(n):
        errands = tuple(pool.task_list[k % len(pool.task_list)])
        pool.restore(TaskEvent(pool.event_seq + 1, pool.next_id, "finished", k % 8,
                               len(errands), 0.0), NewTask(errands))


def replayed(path: Path, fresh: JournaledLifelong) -> tuple[float, int]:
    """Read the journal at ``path`` and replay it into ``fresh``, as a restart does: CPU
    seconds and records."""
    t0 = time.process_time()
    journal = Journal(path)
    records = list(journal.records())
    journal.close()
    replay_shift(records, fresh, on_commands=lambda cs: None, on_report=lambda rec: None,
                 on_start=lambda rec: None)
    return time.process_time() - t0, len(records)


def journal_run(robots: int, seconds: float, every: int, seed: int,
                kept: int = 0) -> dict[str, Any]:
    """The ``--journal`` measurement (see the module doc)."""
    prob = warehouse_problem(robots, seed, (4, 6) if robots <= 200 else (13, 25),
                             p_delay=0.0)
    with tempfile.TemporaryDirectory() as tmp:
        paths = [Path(tmp) / "full.sqlite", Path(tmp) / "compacted.sqlite"]
        journals = [Journal(paths[1]), Journal(paths[0])]
        t0 = time.process_time()
        tune_for_run()  # the garbage collector as the gateway runs a shift
        try:
            shift = journaled_shift(prob, seed, seconds,
                                    [(journals[0], every), (journals[1], 0)], kept=kept)
        finally:
            restore_defaults()
        drive_s = time.process_time() - t0
        for j in journals:
            j.close()
        sizes = [p.stat().st_size for p in paths]
        result = {}
        want = snapshot_shift(shift.live)
        for name, path in zip(("full", "compacted"), paths, strict=True):
            fresh = shift.fresh()
            cpu_s, records = replayed(path, fresh)
            if snapshot_shift(fresh) != want:
                raise SystemExit(f"the {name} journal's replay differs from the live shift")
            result[name] = (records, cpu_s)
    (full_n, full_s), (comp_n, comp_s) = result["full"], result["compacted"]
    return {"robots": robots, "plan_s": seconds, "every": every,
            "segments": shift.live.segments, "actions": sum(shift.live.adg.done),
            "tasks_finished": shift.live.finished_tasks - kept, "kept": kept,
            "full_records": full_n, "full_kb": sizes[0] // 1024, "full_replay_s": round(full_s, 3),
            "compacted_records": comp_n, "compacted_kb": sizes[1] // 1024,
            "compacted_max_records": max(shift.before_compaction, default=comp_n),
            "compacted_replay_s": round(comp_s, 3),
            "compaction_ms_median": round(statistics.median(shift.compact_ms), 1)
            if shift.compact_ms else None,
            "compaction_ms_max": round(max(shift.compact_ms, default=0.0), 1),
            "replay_ratio": round(comp_s / full_s, 4) if full_s else None,
            "drive_cpu_s": round(drive_s, 1), "equal": True}


def main() -> None:
    """Run both parts (or the ``--journal`` measurement) and print one result line."""
    ap = CommandParser(description=__doc__.splitlines()[0])
    ap.add_argument("--ticks", type=int, default=600, help="ticks per LoRR problem")
    ap.add_argument("--robots", type=int, default=1000, help="robots in the speed run")
    ap.add_argument("--seconds", type=int, default=600, help="simulated seconds (speed run)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--delay-seeds", type=int, default=1,
                    help="delay seeds per LoRR problem (mean and min ratio reported)")
    ap.add_argument("--journal", action="store_true",
                    help="measure the shift journal's size and replay time, compacted or not")
    ap.add_argument("--every", type=int, default=60,
                    help="--journal: segments between snapshots of the compacted journal")
    ap.add_argument("--kept", type=int, default=0,
                    help="--journal: ended tasks (and events) the task book starts with, as "
                         "after hours of a shift (at most 100,000 are kept)")
    ap.add_argument("--json", action="store_true",
                    help="print one JSON line (the LoRR problems, --journal's or --scale's)")
    ap.add_argument("--schedulers", default="shortest",
                    help="LoRR problems: comma-separated schedulers to run (default all)")
    ap.add_argument("--lorr", type=Path, default=SHARED,
                    help="the shared LoRR problems (default ../shared/lorr beside the repo)")
    ap.add_argument("--rules-2024", action="store_true",
                    help="also random-example_400 under the 2024 rules vs the 2024 winner "
                         "(as many planner seeds as --delay-seeds)")
    ap.add_argument("--only-2024", action="store_true",
                    help="the LoRR problems: only the --rules-2024 row (implies it)")
    ap.add_argument("--scale", action="store_true",
                    help="the LoRR archive's warehouse_large (10,000) and brc202d (6,500) "
                         "under the 2026 rules (sim_clients/lifelong_scale.py)")
    ap.add_argument("--archive", type=Path, default=None,
                    help=f"--scale: a copy of MAPF-Competition/Benchmark-Archive (default "
                         f"${ARCHIVE_ENV} or ~/.cache/fleetgate/lorr-archive)")
    ap.add_argument("--reassign", type=int, default=LifelongConfig.reassign,
                    help="--scale: planning calls between reassignments of unstarted tasks "
                         "(0: never)")
    ap.add_argument("--station-cap", type=int, default=STATION_CAP,
                    help="--scale: robots sent to one first-errand cell at a time (0: no "
                         "bound)")
    ap.add_argument("--scale-only", default=",".join((*INSTANCES, MILLION)), metavar="NAMES",
                    help="--scale: comma-separated instances to run (default all: "
                         f"{', '.join((*INSTANCES, MILLION))})")
    ap.add_argument("--scale-one", choices=sorted((*INSTANCES, MILLION)),
                    help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.scale_one:
        print(json.dumps(scale_one(args.scale_one, archive_dir(args.archive), args.ticks,
                                   args.reassign, args.station_cap or None)))
        return
    if args.scale:
        names = [n for n in args.scale_only.split(",") if n]
        unknown = sorted(set(names) - {*INSTANCES, MILLION})
        if unknown:
            ap.error(f"--scale-only: unknown instance {unknown[0]!r}")
        scaled = scale_runs(archive_dir(args.archive), args.ticks, args.reassign,
                            [sys.executable, __file__], names, args.station_cap or None)
        print(json.dumps(scaled) if args.json else scale_line(scaled))
        return
    if args.journal:
        out = journal_run(args.robots, args.seconds, args.every, args.seed, args.kept)
        print(json.dumps(out) if args.json else
              f"lifelong journal: {out['robots']} robots x {out['plan_s']} s of plan time "
              f"({out['actions']} actions): uncompacted {out['full_records']} "
              f"records, {out['full_kb']} KB, replayed in {out['full_replay_s']} s CPU; "
              f"compacted every {out['every']} segments {out['compacted_records']} records "
              f"(at most {out['compacted_max_records']}), {out['compacted_kb']} KB, replayed "
              f"in {out['compacted_replay_s']} s CPU; replay_ratio {out['replay_ratio']}; "
              "both replays equal the live shift")
        return
    parts = []
    if args.lorr.is_dir():
        schedulers = args.schedulers.split(",")
        unknown = sorted(set(schedulers) - set(SCHEDULERS))
        if unknown:
            ap.error(f"unknown scheduler(s) {', '.join(unknown)}; expected {sorted(SCHEDULERS)}")
        runs = ([] if args.only_2024 else
                shared_runs(args.lorr, args.ticks, args.delay_seeds, schedulers))
        rules = ([rules_2024_run(args.lorr, s, args.delay_seeds) for s in schedulers]
                 if args.rules_2024 or args.only_2024 else [])
        if args.json:
            print(json.dumps({"ticks": args.ticks, "delay_seeds": args.delay_seeds,
                              "lorr": runs, "rules_2024": rules,
                              "worst_ratio": min((r["min_ratio"] for r in runs),
                                                 default=None)}))
            return
        entries = [f"{r['problem']}/{r['scheduler']} {r['mean']:.0f}/{r['reference']:.0f}="
                   f"{r['ratio']:.2f} (min {r['min_ratio']:.2f})" for r in runs]
        entries += [f"{r['problem']}/{r['scheduler']} {r['mean']:.0f}/{r['winner']}="
                    f"{r['ratio']:.2f} (min {r['min_ratio']:.2f})" for r in rules]
        parts.append("tasks vs LoRR reference: " + ", ".join(entries)
                     + f"; collisions 0 over {args.delay_seeds} delay seed(s)")
    elif args.json:
        print(json.dumps({"skipped": f"{args.lorr} absent"}))
        return
    else:
        parts.append(f"LoRR problems skipped ({args.lorr} absent)")
    cpu, finished, cells = speed_run(args.robots, args.seconds, args.seed)
    parts.append(f"speed: {args.robots} robots x {args.seconds} s on {cells} free cells "
                 f"({finished} tasks) in {cpu:.1f} s CPU = {cpu / 60:.2f} x the 60 s goal "
                 f"(LSMART: 268 s on 16 cores)")
    print("lifelong: " + "; ".join(parts))


if __name__ == "__main__":
    run_main("bench/lifelong.py", main)
