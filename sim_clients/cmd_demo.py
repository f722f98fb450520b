"""``fleetgate demo``: the gateway, a simulated fleet and the operator GUI in one process.

Everything talks over real websockets on loopback in real time: the gateway listens on
``--host:--port`` (GUI at ``http://H:P/``), the simulated robots and the world connect to it
like remote ones would. Actions last ``1000 / speed`` ms of wall time; every reported time is
plan time (wall time x speed). The first run starts when the GUI is first opened (an operator
connects; ``--start now`` or ``--headless``: at once), so whoever opens it sees the intruder
and the replan; without ``--headless`` the gateway keeps serving the GUI afterwards (load,
start, pause, intruders...) until Ctrl-C.

The operator token is random for each run and printed once, in the GUI's login URL
(``/login#token=...``: the fragment never reaches a server or a log).
"""

from __future__ import annotations

import argparse
import contextlib
import json
import secrets
import sys
from pathlib import Path
from typing import TYPE_CHECKING

from fleetgate.userio.files import check_writable
from gateway.commands.instance_args import add_instance_arguments, add_motion_arguments
from gateway.commands.progress import StatusLine
from gateway.commands.solving import (
    add_planning_arguments,
    check_planning_arguments,
    no_solution_message,
    solve_instance,
)
from gateway.execution.oneshot.policies import POLICY_NAMES
from gateway.execution.params import PAPER
from gateway.runtime.exits import EXIT_INTERRUPTED, EXIT_NO_SOLUTION, UsageError
from sim_clients.cmd_demo_lifelong import add_lifelong_arguments, run_lifelong_demo
from sim_clients.demo_instance import DEFAULT_AGENTS, DEFAULT_MAP, DEFAULT_SCEN
from sim_clients.stays import STAY_HELP, stay_option

if TYPE_CHECKING:
    from collections.abc import AsyncIterator

    from gateway.server.config import GatewayConfig
    from gateway.server.engine import Engine
    from gateway.server.gateway import Gateway
    from gateway.server.planner import Problem
    from gateway.vda5050.config import Vda5050Config
    from sim_clients.fleet import SimFleet
    from sim_clients.intruder import IntruderConfig


STATUS_PERIOD_S = 0.25
"""How often the terminal's status line is redrawn (wall time)."""


def status_text(engine: Engine) -> str:
    """The live status: ``t 12.3 s | robots done 4/10 | slack 2.1 s | replans 1 | running``."""
    ex = engine.executor
    if ex is None:
        return f"gateway {engine.status}"
    n = ex.adg.n_robots
    done = sum(1 for r in range(n) if ex.monitor.next_vertex(r) < 0)
    slack = ex.monitor.fleet_slack()
    return (f"t {engine.now_ms() / 1000:.1f} s | robots done {done}/{n} | slack "
            f"{slack / 1000:.1f} s | replans {ex.replans} | {engine.status}")


def run_summary(engine: Engine, collisions: int) -> str:
    """One line for a finished run, the same whether the command or the GUI started it:
    SOC, makespan, replans and the world's collisions during the run."""
    soc, makespan = engine.summary or (0.0, 0.0)
    replans = engine.executor.replans if engine.executor is not None else 0
    return (f"run complete: SOC {soc:.0f} ms, makespan {makespan:.0f} ms, "
            f"{replans} replan(s), {collisions} collisions")


async def show_status(engine: Engine, status: StatusLine) -> None:
    """Redraw the status line until cancelled (on a terminal; elsewhere it returns)."""
    import asyncio

    if not status.live:
        return
    try:
        while True:
            status.set(status_text(engine))
            await asyncio.sleep(STATUS_PERIOD_S)
    finally:
        status.clear()


def _follow_runs(gateway: Gateway, fleet: SimFleet, status: StatusLine,
                 intruder: bool) -> None:
    """After the first run, an operator may load and start others: give every agent a
    robot, put the robots on the plan's starts whenever a new run begins (and, with
    ``intruder``, bring the automatic intruder again, so each run shows a replan), and print
    a summary line when a run ends."""
    engine = gateway.engine
    previous: list[str] = [engine.status]
    collisions_before = [len(fleet.world.collisions)]

    def on_status(now: str) -> None:
        was, previous[0] = previous[0], now
        problem = engine.problem
        if problem is None:
            return
        if now == "loaded":
            for r in range(problem.instance.num_agents):
                fleet.add_robot(r)
        if now == "running" and was in ("loaded", "done") and engine.executor is not None:
            plan = engine.executor.plan
            fleet.place_all([p[0] for p in plan.paths],
                            None if plan.headings is None else [h[0] for h in plan.headings])
            if intruder:
                fleet.rearm_intruder()
            collisions_before[0] = len(fleet.world.collisions)
        if now == "done" and was != "done":
            collisions = len(fleet.world.collisions) - collisions_before[0]
            status.print(run_summary(engine, collisions))

    engine.status_listeners.append(on_status)


async def first_operator(engine: Engine) -> None:
    """Until an operator is connected (the GUI was opened and logged in)."""
    import asyncio

    while not engine.feed.operators:
        await asyncio.sleep(0.05)


def demo_intruder(args: argparse.Namespace) -> IntruderConfig:
    """The demo's automatic intruder: the paper's, or with ``--intruder-stay`` a stay drawn
    from the run's seed."""
    from sim_clients.intruder import IntruderConfig

    stay = stay_option(args.intruder_stay)
    return IntruderConfig(stay_ms=None if stay is None else stay.draw_ms(args.seed))


async def all_online(engine: Engine, robots: int) -> None:
    """Until every robot (websocket or VDA 5050) is connected."""
    import asyncio

    while not engine.all_online(robots):
        await asyncio.sleep(0.05)


@contextlib.asynccontextmanager
async def vda_vehicles(gateway: Gateway, problem: Problem, vda: Vda5050Config,
                       fleet: SimFleet, speed: float) -> AsyncIterator[None]:
    """Simulated VDA 5050 vehicles on the plan's starts (on ``fleet``'s floor, where its
    intruder walks) and the gateway's master control for them, while the block runs."""
    import asyncio

    from gateway.vda5050.transport import VdaTransport
    from sim_clients.vda_fleet import make_vehicles, run_fleet

    plan = problem.plan
    assert plan is not None
    starts = problem.instance.starts
    vehicles = make_vehicles(vda, fleet.world, speed=speed, starts={
        r: (starts[r], plan.headings[r][0] if plan.headings is not None else None)
        for r in range(len(starts))})
    stop = asyncio.Event()
    running = asyncio.ensure_future(run_fleet(vehicles, vda.broker, stop))
    try:
        async with VdaTransport(gateway, vda):
            yield
    finally:
        stop.set()
        await asyncio.gather(running, return_exceptions=True)


async def _demo(config: GatewayConfig, problem: Problem, args: argparse.Namespace,
                status: StatusLine, vda: Vda5050Config | None = None) -> int:
    import asyncio

    from fleetgate.userio.signals import StopSignals
    from gateway.server.clock import RealClock, VirtualClock
    from gateway.server.gateway import Gateway
    from sim_clients.connect import websocket_connector
    from sim_clients.fleet import fleet_for, run_in_process
    from sim_clients.summary import RunSummary

    stop = StopSignals()
    agents = problem.instance.num_agents
    clock = VirtualClock(config.speed) if args.virtual_time else RealClock(config.speed)
    async with Gateway(config, clock=clock) as gateway, \
            contextlib.AsyncExitStack() as vehicles:
        port = await gateway.listen()
        host = config.host
        token = config.tokens.operators[0]
        status.print(f"fleetgate demo: GUI at http://{host}:{port}/login#token={token} "
                     f"(robots and world on ws://{host}:{port}/ws)")
        fleet = fleet_for(gateway, 0 if vda is not None else agents,
                          websocket_connector(f"ws://{host}:{port}/ws"),
                          seed=args.seed, intruder=args.intruder,
                          intruder_config=demo_intruder(args), poll_at_ticks=False,
                          send_state=True)
        if vda is not None:
            await vehicles.enter_async_context(vda_vehicles(gateway, problem, vda, fleet,
                                                            args.speed))
            status.print(f"fleetgate demo: {agents} VDA 5050 vehicles on {vda.broker.url}")
        watched = not args.headless and args.start == "login"
        if watched:
            status.print("fleetgate demo: the run starts when you open the GUI "
                         "(--start now: at once)")

        async def before_start() -> None:
            await all_online(gateway.engine, agents)
            if watched:
                await first_operator(gateway.engine)

        run = asyncio.ensure_future(run_in_process(gateway, problem, fleet, before_start))
        stopped = asyncio.ensure_future(stop.wait())
        live = asyncio.ensure_future(show_status(gateway.engine, status))
        try:
            await asyncio.wait({run, stopped}, return_when=asyncio.FIRST_COMPLETED)
            if not run.done():
                status.print("fleetgate demo: interrupted before the run completed")
                return EXIT_INTERRUPTED
            result: RunSummary = run.result()
            if args.json:
                print(json.dumps(result.summary()), flush=True)
            else:
                status.print(run_summary(gateway.engine, result.collisions))
            if not args.headless:
                _follow_runs(gateway, fleet, status, args.intruder)
                status.print("serving the GUI until Ctrl-C")
                await stopped
            return stop.exit_code
        finally:
            for task in (run, stopped, live):
                task.cancel()
            await asyncio.gather(run, stopped, live, return_exceptions=True)
            await fleet.stop()


def _run(args: argparse.Namespace) -> int:
    import asyncio

    from gateway.commands.instance_args import instance_from_args, starts_from_args
    from gateway.planning.plan import NoSolution
    from gateway.planning.seeds import run_seed
    from gateway.server.clock import run_paced
    from gateway.server.config import ConfigError, load_config
    from gateway.server.logs import configure_logging
    from gateway.server.planner import Problem

    if args.virtual_time and (args.lifelong or args.vda5050):
        raise UsageError("--virtual-time runs a one-shot demo over websockets, not "
                         f"{'--lifelong' if args.lifelong else '--vda5050'}")
    if args.lifelong:
        if args.vda5050:
            raise UsageError("--vda5050 runs one-shot plans, not --lifelong (yet)")
        return run_lifelong_demo(args)
    if not 0 < args.speed <= 100:
        raise UsageError(f"--speed must be in (0, 100], got {args.speed:g}")
    if args.threshold_ms < 0:
        raise UsageError(f"--threshold-ms must be >= 0, got {args.threshold_ms:g}")
    if args.max_replans < 0:
        raise UsageError(f"--max-replans must be >= 0, got {args.max_replans}")
    check_planning_arguments(args)
    stay_option(args.intruder_stay)  # bad input before planning
    instance = instance_from_args(args)
    status = StatusLine()
    try:
        plan = solve_instance(instance, args, status, motion=args.motion,
                              starts=starts_from_args(args, instance)).plan
    except NoSolution as exc:
        why = no_solution_message(instance, args, str(exc), exc.timed_out)
        print(f"fleetgate: {why}", file=sys.stderr)
        return EXIT_NO_SOLUTION
    if args.trace:
        check_writable(args.trace, "the trace")  # an earlier one is moved aside, not lost
    try:
        config = load_config(None, host=args.host, port=args.port, map=None, speed=args.speed,
                             policy=args.policy, threshold_ms=args.threshold_ms,
                             policy_seed=run_seed(args.seed, "replan"), trace=args.trace,
                             solver_time_limit_s=args.time_limit, fallback_s=args.fallback,
                             max_replans=args.max_replans, log_level=args.log_level,
                             log_format=args.log_format, log_file=args.log_file,
                             dispatch_lookahead=args.lookahead, motion=args.motion,
                             tokens={"operators": [secrets.token_urlsafe(24)]})
    except ConfigError as exc:
        raise UsageError(str(exc)) from None
    try:
        configure_logging(config.log_level, config.log_format, config.log_file, status.stream)
    except OSError as exc:
        raise UsageError(f"cannot write the log file {args.log_file}: {exc.strerror}") from None
    # the names the GUI's Instance form shows and loads again: the map's, the scenario's
    problem = Problem(instance, Path(args.map).stem if args.map else instance.name, plan,
                      scen_name=Path(args.scen).stem if args.scen else "")
    with contextlib.ExitStack() as broker:
        vda = demo_vda_settings(args, instance.num_agents, broker)
        try:
            demo = _demo(config, problem, args, status, vda)
            return run_paced(demo) if args.virtual_time else asyncio.run(demo)
        except OSError as exc:
            raise UsageError(f"cannot listen on {config.host}:{config.port}: {exc.strerror}"
                             ) from None
        except ValueError as exc:  # the MQTT broker cannot be reached
            raise UsageError(str(exc)) from None


def demo_vda_settings(args: argparse.Namespace, robots: int, stack: contextlib.ExitStack
                      ) -> Vda5050Config | None:
    """With ``--vda5050``: every robot a VDA 5050 vehicle (``fleetgate``/``sim<id>``) on
    ``--broker``, or on a private mosquitto started for the demo (stopped with ``stack``)."""
    if not args.vda5050:
        if args.broker is not None:
            raise UsageError("--broker needs --vda5050")
        return None
    from gateway.vda5050.broker import BrokerConfig
    from gateway.vda5050.config import Vda5050Config, VehicleConfig
    from sim_clients.mosquitto import LocalBroker, MosquittoMissing

    url = args.broker
    if url is None:
        try:
            url = stack.enter_context(LocalBroker())
        except (MosquittoMissing, RuntimeError) as exc:
            raise UsageError(str(exc)) from None
    try:
        return Vda5050Config(broker=BrokerConfig(url=url), version=args.vda_version,
                             vehicles=[VehicleConfig(manufacturer="fleetgate",
                                                     serial_number=f"sim{r}", robot_id=r)
                                       for r in range(robots)])
    except ValueError as exc:
        raise UsageError(f"--broker: {str(exc).splitlines()[-1].strip()}") from None


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    """Add ``fleetgate demo``."""
    p = sub.add_parser(
        "demo", help="gateway + simulated fleet + GUI on loopback (zero setup)",
        description="Plan the instance, start the gateway on HOST:PORT, connect a simulated "
                    "robot per agent and the simulated world over websockets, and execute the "
                    "plan in real time (an action lasts 1000/SPEED ms; reported times are plan "
                    "time). The GUI is at http://HOST:PORT/ and stays up after the run until "
                    "Ctrl-C unless --headless. Defaults: 10 robots on the lab map, slack "
                    "policy, intruder on. Exit codes: 0 success, 2 bad input, 3 no plan.")
    p.add_argument("--host", default="127.0.0.1", help="address (default 127.0.0.1)")
    p.add_argument("--port", type=int, default=8080, help="port (default 8080; 0 = any free)")
    p.add_argument("--headless", action="store_true",
                   help="start at once, exit when the first run is complete instead of "
                        "serving the GUI")
    p.add_argument("--start", choices=["login", "now"], default="login",
                   help="when the first run starts: when the GUI is first opened (default, "
                        "so you see the intruder and the replan), or at once")
    p.add_argument("--json", action="store_true",
                   help='print the run like "fleetgate simulate --json": {"soc_ms", '
                        '"makespan_ms", "plan_soc", "replans", "replan_at_ms", "solver_ms", '
                        '"collisions"}')
    p.add_argument("--trace", metavar="FILE.jsonl", help="write the JSON-lines trace here")
    p.add_argument("--virtual-time", action="store_true",
                   help="simulated time held to the wall clock's pace: every run of a seed "
                        "has the same times whatever else the machine runs (a starved "
                        "process runs slower instead of late); a replan takes no plan time")
    add_lifelong_arguments(p)
    add_instance_arguments(p)
    add_motion_arguments(p, default="omni")
    p.set_defaults(map=DEFAULT_MAP, scen=DEFAULT_SCEN, agents=DEFAULT_AGENTS)
    p.add_argument("--speed", metavar="F", type=float, default=1.0,
                   help="the world runs F times faster than plan time (default 1)")
    p.add_argument("--intruder", action=argparse.BooleanOptionalAction, default=True,
                   help=f"the intruder appears at {PAPER.intruder_appear_ms:g} ms and leaves at "
                   f"{PAPER.intruder_leave_ms:g} ms of every run, those started from the GUI "
                   "too (default: on)")
    p.add_argument("--intruder-stay", metavar="SPEC|FILE", help=STAY_HELP)
    p.add_argument("--policy", choices=POLICY_NAMES, default="slack",
                   help="replanning policy (default slack)")
    p.add_argument("--threshold-ms", metavar="MS", type=float, default=PAPER.threshold_ms,
                   help="fleet slack threshold of the slack policy "
                   f"(default {PAPER.threshold_ms:g})")
    p.add_argument("--seed", metavar="K", type=int, default=0,
                   help="seed of the intruder's choice and the random policy (default 0)")
    add_planning_arguments(p, 30.0)
    p.add_argument("--max-replans", metavar="N", type=int, default=1,
                   help="replans allowed per run, the operator's included (default 1)")
    p.add_argument("--log-level", choices=["DEBUG", "INFO", "WARNING", "ERROR"],
                   default="WARNING", help="gateway log level (default WARNING)")
    p.add_argument("--log-format", choices=["text", "json"], default="text",
                   help="gateway log lines: readable text (default) or JSON objects")
    p.add_argument("--log-file", metavar="FILE", type=Path,
                   help="append the gateway's logs here instead of stderr")
    p.add_argument("--vda5050", action="store_true",
                   help="the robots are simulated VDA 5050 vehicles driven over MQTT "
                        "(docs/vda5050.md); a private mosquitto is started unless --broker")
    p.add_argument("--broker", metavar="URL",
                   help="with --vda5050: an MQTT broker mqtt://HOST:PORT to use instead")
    p.add_argument("--vda-version", choices=["2.0.0", "2.1.0"], default="2.1.0",
                   help="with --vda5050: the vehicles' protocol version (default 2.1.0)")
    p.add_argument("--lookahead", metavar="N", type=int, default=1,
                   help="actions queued on a robot beyond its current one (default 1: the next "
                        "action is released early, so a robot need not wait for a round trip; "
                        "0 = classic dispatch)")
    p.set_defaults(func=_run)
