"""``fleetgate demo --lifelong``: a warehouse shift with a simulated fleet over real websockets.

The gateway runs in lifelong mode (a generated warehouse, or ``--problem`` a LoRR problem),
the simulated robots connect on loopback like remote ones, and the shift starts when all are
online. Tasks stream in from the problem's task list (the LoRR Start-Kit's reveal rule); the
terminal shows a live status line (tasks finished, tasks per minute, robots, queue) until
Ctrl-C or SIGTERM (or ``--seconds`` of plan time; on a pipe or in a log the status is a line
every few seconds), then the shift stops: robots finish what they were dispatched and a
summary line (or ``--json``) is printed. After ``--seconds`` the GUI stays up until Ctrl-C
unless ``--headless``, as after a one-plan demo's run.
"""

from __future__ import annotations

import argparse
import json
import secrets
from pathlib import Path
from typing import TYPE_CHECKING

from fleetgate.userio.exits import quiet_stdout
from fleetgate.userio.files import check_writable
from gateway.runtime.exits import UsageError

if TYPE_CHECKING:
    from gateway.commands.progress import StatusLine
    from gateway.server.config import GatewayConfig
    from gateway.server.engine import Engine

STATUS_PERIOD_S = 0.25
"""How often the status line is redrawn on a terminal (wall time)."""
LOG_PERIOD_S = 5.0
"""How often the status is printed as a line of its own when stderr is no terminal (a pipe,
a log file, journald)."""
DEFAULT_ROBOTS = 20


def shift_status(engine: Engine) -> str:
    """``t 61.0 s | tasks 25 (24.6/min) | robots 20/20 | queue 30 | running``."""
    run = engine.lifelong
    if run is None:
        return f"gateway {engine.status}"
    from gateway.server.views import throughput_per_min

    ex = run.executor
    t = engine.now_ms() if ex.mode.value != "new" else 0.0
    rate = throughput_per_min(ex.finished_tasks, t)  # the GUI's figure too (its snapshot)
    return (f"t {t / 1000:.1f} s | tasks {ex.finished_tasks} ({rate:.1f}/min) | robots "
            f"{engine.connected_robots()}/{run.robots} | queue {len(run.tasks.open)} | "
            f"{engine.status}")


async def _show(engine: Engine, status: StatusLine) -> None:
    """The live status until cancelled: redrawn in place on a terminal, else a line every
    :data:`LOG_PERIOD_S`."""
    import asyncio

    try:
        while True:
            if status.live:
                status.set(shift_status(engine))
                await asyncio.sleep(STATUS_PERIOD_S)
            else:
                await asyncio.sleep(LOG_PERIOD_S)
                status.print(shift_status(engine))
    finally:
        status.clear()


async def _shift(config: GatewayConfig, args: argparse.Namespace, status: StatusLine) -> int:
    import asyncio

    from fleetgate.userio.signals import StopSignals
    from gateway.server.gateway import Gateway
    from sim_clients.connect import websocket_connector
    from sim_clients.fleet import SimFleet
    from sim_clients.shift import start_shift, stop_shift

    stop = StopSignals()
    async with Gateway(config) as gateway:
        port = await gateway.listen()
        run = gateway.engine.lifelong
        assert run is not None
        host = config.host
        status.print(f"fleetgate demo --lifelong: {run.robots} robots on {run.shift.name} "
                     f"({int(run.shift.grid.free.sum())} free cells); GUI at http://{host}:"
                     f"{port}/login#token={config.tokens.operators[0]}")
        fleet = SimFleet(websocket_connector(f"ws://{host}:{port}/ws"), range(run.robots),
                         clock=gateway.clock, send_state=True, duration_jitter=0.1,
                         seed=args.seed)
        live = asyncio.ensure_future(_show(gateway.engine, status))
        try:
            await start_shift(gateway, fleet)
            status.print("shift started: Ctrl-C stops it"
                         + (f" (or {args.seconds:g} s of plan time)" if args.seconds else ""))
            stopped = asyncio.ensure_future(stop.wait())
            while not stopped.done() and not (
                    args.seconds and gateway.engine.now_ms() >= args.seconds * 1000.0):
                await asyncio.wait({stopped}, timeout=0.05)
            stopped.cancel()
            stats = await stop_shift(gateway, fleet)
        finally:
            live.cancel()
            await asyncio.gather(live, return_exceptions=True)
            await fleet.stop()
        minutes = stats.elapsed_ms / 60_000.0
        wait = run.wait_percentiles_s()
        result = {"tasks_finished": stats.finished_tasks, "plan_s": stats.elapsed_ms / 1000.0,
                  "tasks_per_min": stats.finished_tasks / minutes if minutes else 0.0,
                  "robots": run.robots, "dispatched": stats.dispatched, "lost": stats.lost,
                  "duplicated": stats.duplicated, "collisions": stats.collisions,
                  "assignment_wait_s": wait}
        if args.json:
            try:
                print(json.dumps(result), flush=True)
            except BrokenPipeError:  # nobody reads it: how the shift ended still sets the code
                quiet_stdout()
        else:
            status.print(f"shift stopped: {stats.finished_tasks} tasks in "
                         f"{result['plan_s']:.1f} s ({result['tasks_per_min']:.1f}/min), "
                         f"{stats.dispatched} actions, {stats.lost} lost, {stats.duplicated} "
                         f"duplicated, {stats.collisions} collisions; assignment wait p50 "
                         f"{wait['p50']:.1f} s, max {wait['max']:.1f} s")
        if not (args.headless or stop.event.is_set()):  # --seconds ended it: the GUI stays up
            status.print("serving the GUI until Ctrl-C")
            await stop.wait()
    return stop.exit_code


def run_lifelong_demo(args: argparse.Namespace) -> int:
    """``fleetgate demo --lifelong``: check the arguments, run the shift."""
    import asyncio

    from gateway.commands.progress import StatusLine
    from gateway.planning.lorr import warehouse_blocks
    from gateway.server.config import ConfigError, LifelongSettings, load_config
    from gateway.server.logs import configure_logging

    if not 0 < args.speed <= 100:
        raise UsageError(f"--speed must be in (0, 100], got {args.speed:g}")
    robots = args.robots if args.robots is not None else DEFAULT_ROBOTS
    if robots < 1:
        raise UsageError(f"--robots must be >= 1, got {robots}")
    if args.seconds is not None and args.seconds <= 0:
        raise UsageError(f"--seconds must be > 0, got {args.seconds:g}")
    problem = Path(args.problem) if args.problem else None
    if problem is not None and not problem.is_file():
        raise UsageError(f"LoRR problem not found: {problem}")
    if args.trace:
        check_writable(args.trace, "the trace")  # an earlier one is moved aside, not lost
    status = StatusLine()
    try:
        config = load_config(
            None, host=args.host, port=args.port, map=None, speed=args.speed, autostart=True,
            trace=args.trace, log_level=args.log_level, log_format=args.log_format,
            log_file=args.log_file, dispatch_lookahead=args.lookahead,
            motion="omni" if args.motion == "omni" else "turning",
            tokens={"operators": [secrets.token_urlsafe(24)]},
            lifelong=LifelongSettings(problem=problem, robots=robots, seed=args.seed,
                                      warehouse=warehouse_blocks(robots)))
        configure_logging(config.log_level, config.log_format, config.log_file, status.stream)
    except ConfigError as exc:
        raise UsageError(str(exc)) from None
    except OSError as exc:
        raise UsageError(f"cannot write the log file {args.log_file}: {exc.strerror}") from None
    try:
        return asyncio.run(_shift(config, args, status))
    except ValueError as exc:  # the problem cannot be read
        raise UsageError(str(exc)) from None
    except OSError as exc:
        raise UsageError(f"cannot listen on {config.host}:{config.port}: {exc.strerror}"
                         ) from None


def add_lifelong_arguments(p: argparse.ArgumentParser) -> None:
    """The demo's lifelong options."""
    p.add_argument("--lifelong", action="store_true",
                   help="run a warehouse shift (lifelong mode) instead of one plan: robots get "
                        "tasks from a task stream until Ctrl-C")
    p.add_argument("--robots", metavar="N", type=int,
                   help=f"--lifelong: robots in the generated warehouse (default "
                        f"{DEFAULT_ROBOTS})")
    p.add_argument("--problem", metavar="PROBLEM.json",
                   help="--lifelong: a LoRR problem (map, robots, task list) instead of the "
                        "generated warehouse")
    p.add_argument("--seconds", metavar="S", type=float,
                   help="--lifelong: stop the shift after S seconds of plan time (default: "
                        "at Ctrl-C); the GUI stays up until Ctrl-C unless --headless")
