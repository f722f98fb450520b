"""``fleetgate conformance gateway|robot``: arguments, running a checklist, printing results.

Exit codes: 0 every required check passed, 1 a required check failed, 2 bad invocation or a
target that cannot be reached (one line on stderr, never a traceback).
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Any
from urllib.parse import urlsplit

from conformance.report import (
    EXIT_USAGE,
    CheckResult,
    UsageProblem,
    as_json,
    as_text,
    exit_code,
    write_junit,
)

if TYPE_CHECKING:  # the checks (websockets, pydantic) are imported when a mode runs
    from conformance.checklist import Checklist


def _ws_url(value: str) -> str:
    parts = urlsplit(value)
    if parts.scheme not in ("ws", "wss") or not parts.hostname:
        raise UsageProblem(f"expected a ws:// or wss:// URL, got {value!r}")
    try:
        parts.port  # noqa: B018 (validates the port)
    except ValueError:
        raise UsageProblem(f"bad port in {value!r}") from None
    return value


def _only(value: str | None, checklist: Checklist[Any]) -> set[str] | None:
    if value is None:
        return None
    names = {n.strip() for n in value.split(",") if n.strip()}
    known = {c.name for c in checklist.checks}
    unknown = sorted(names - known)
    if unknown:
        raise UsageProblem(f"unknown check {unknown[0]!r} (--list shows them)")
    return names


def _list(checklist: Checklist[Any]) -> int:
    for c in checklist.checks:
        kind = "required" if c.required else "optional"
        print(f"{c.name:36} {c.rule:11} {kind:8}  {c.doc}")
    return 0


def _output(results: list[CheckResult], args: argparse.Namespace, target: str) -> int:
    if args.junit is not None:
        write_junit(results, f"fleetgate-conformance-{args.mode}", Path(args.junit))
    print(as_json(results) if args.json else as_text(results, target))
    return exit_code(results)


def _gateway(args: argparse.Namespace) -> int:
    import asyncio

    from conformance.gateway_checks import GATEWAY_CHECKS, run_gateway_checks
    from conformance.target import Options

    if args.list:
        return _list(GATEWAY_CHECKS)
    if args.url is None or args.token is None:
        raise UsageProblem("give the gateway's URL and --token (see --help)")
    if args.robot_id < 0 or (args.peer_id is not None and args.peer_id < 0):
        raise UsageProblem("robot ids are >= 0")
    if args.peer_id is not None and args.peer_id == args.robot_id:
        raise UsageProblem("--peer-id must differ from --robot-id")
    options = Options(url=_ws_url(args.url), token=args.token, robot_id=args.robot_id,
                      peer_id=args.peer_id, peer_token=args.peer_token,
                      operator_token=args.operator_token, map=args.map, cafile=args.cafile,
                      robot_version=args.robot_version)
    only = _only(args.only, GATEWAY_CHECKS)
    results = asyncio.run(run_gateway_checks(options, only))
    return _output(results, args, args.url)


def _robot(args: argparse.Namespace) -> int:
    import asyncio

    from conformance.robot_checks import ROBOT_CHECKS, RobotOptions, run_robot_checks

    if args.list:
        return _list(ROBOT_CHECKS)
    if (args.url is None) == (args.command is None):
        raise UsageProblem("give exactly one of --url (listen there and wait for the robot) "
                           "and --command (start the robot with {url} substituted)")
    if args.command is not None and "{url}" not in args.command:
        raise UsageProblem("--command must contain {url} (where the robot should connect)")
    if args.robot_id < 0:
        raise UsageProblem("--robot-id must be >= 0")
    if args.timeout <= 0:
        raise UsageProblem("--timeout must be positive")
    listen = _ws_url(args.url) if args.url is not None else None
    if listen is not None and urlsplit(listen).scheme != "ws":
        raise UsageProblem("the checker listens on plain ws:// (put a TLS proxy in front)")
    token = args.token or f"conformance-robot-{args.robot_id}"
    options = RobotOptions(robot_id=args.robot_id, token=token, listen=listen,
                           command=args.command, connect_timeout_s=args.timeout)
    only = _only(args.only, ROBOT_CHECKS)
    results = asyncio.run(run_robot_checks(options, only))
    return _output(results, args, args.command or args.url)


def _vda5050(args: argparse.Namespace) -> int:
    import asyncio

    from conformance.vda5050.checks import VDA_CHECKS, run_vda_checks
    from conformance.vda5050.schemas import DEFAULT_DIR
    from conformance.vda5050.session import Broker, VdaOptions
    from protocol.vda5050.topics import VehicleTopics

    if args.list:
        return _list(VDA_CHECKS)
    if args.broker is None or args.manufacturer is None or args.serial is None:
        raise UsageProblem("give --broker, --manufacturer and --serial (see --help)")
    try:
        VehicleTopics(args.interface, "v2", args.manufacturer, args.serial)
    except ValueError as exc:
        raise UsageProblem(str(exc)) from None
    if not 0 < args.step <= 100 or args.timeout <= 0:
        raise UsageProblem("--step must be in (0, 100] metres and --timeout positive")
    parts = urlsplit(args.broker)
    try:
        parts.port  # noqa: B018 (validates the port)
    except ValueError:
        raise UsageProblem(f"--broker: bad port in {args.broker!r}") from None
    if parts.scheme not in ("mqtt", "mqtts") or not parts.hostname or parts.path not in (
            "", "/"):
        raise UsageProblem(f"--broker: expected mqtt://HOST:PORT or mqtts://HOST:PORT, got "
                           f"{args.broker!r}")
    broker = Broker(args.broker, args.username, os.environ.get(args.password_env)
                    if args.password_env else None, args.cafile)
    options = VdaOptions(broker=broker, manufacturer=args.manufacturer, serial=args.serial,
                         version=args.version, interface=args.interface, step_m=args.step,
                         command=args.command, timeout_s=args.timeout,
                         schemas=Path(args.schemas) if args.schemas else DEFAULT_DIR)
    only = _only(args.only, VDA_CHECKS)
    results = asyncio.run(run_vda_checks(options, only))
    return _output(results, args, f"{args.manufacturer}/{args.serial} on {args.broker}")


def run(args: argparse.Namespace) -> int:
    """Run the chosen mode; UsageProblem becomes a one-line error and exit code 2 (Ctrl-C,
    a closed pipe and an unwritable output end as every command's: :mod:`fleetgate.userio`)."""
    modes = {"gateway": _gateway, "robot": _robot, "vda5050": _vda5050}
    try:
        return int(modes[args.mode](args))
    except UsageProblem as exc:
        print(f"fleetgate conformance: {exc}", file=sys.stderr)
        return EXIT_USAGE


def _common(p: argparse.ArgumentParser) -> None:
    p.add_argument("--json", action="store_true",
                   help='print {"passed": bool, "checks": [...]} instead of text')
    p.add_argument("--junit", metavar="FILE", help="also write the results as JUnit XML")
    p.add_argument("--only", metavar="NAMES", help="run only these checks (comma-separated)")
    p.add_argument("--list", action="store_true", help="list the checks and exit")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """The ``gateway`` and ``robot`` subcommands of ``fleetgate conformance``."""
    modes = parser.add_subparsers(dest="mode", required=True, metavar="MODE")
    g = modes.add_parser(
        "gateway", help="check a gateway (the checker plays robots and an operator)",
        description="Drive a gateway through the protocol checklist (docs/protocol.md). "
                    "It needs a robot token and an operator token (to load tiny plans on "
                    "--map; the checker switches replanning off while it runs and restores "
                    "the policy). Against a zero-setup `fleetgate serve`: "
                    "fleetgate conformance gateway ws://127.0.0.1:8080/ws --token "
                    "'demo-robot-{id}' --operator-token demo-operator")
    g.add_argument("url", nargs="?", metavar="URL", help="the gateway's ws:// or wss:// URL")
    g.add_argument("--token", help="the robot's token; a template with {id} gives every "
                                   "robot's (needed for the two-robot checks)")
    g.add_argument("--robot-id", type=int, default=0, help="the robot the token is for "
                                                           "(default 0)")
    g.add_argument("--peer-id", type=int, help="second robot (default robot id + 1)")
    g.add_argument("--peer-token", help="the second robot's token (unless --token has {id})")
    g.add_argument("--operator-token", help="operator token (loads the checker's plans)")
    g.add_argument("--map", default="lab", help="map the plans are loaded on (default lab; "
                                                "needs five free cells in a row)")
    g.add_argument("--cafile", help="CA certificate to trust for wss://")
    g.add_argument("--robot-version", type=int, choices=[2, 3], default=3,
                   help="the protocol version the checker's robots speak (default 3: no ack; "
                        "2: an ack per action); one check plays a version 1 robot, one a "
                        "version 2 robot whatever this says")
    _common(g)
    r = modes.add_parser(
        "robot", help="check a robot (the checker plays the gateway)",
        description="Play a gateway against a robot implementation, through the protocol "
                    "checklist (docs/protocol.md). The checker listens on --url (and waits "
                    "for the robot) or on an ephemeral 127.0.0.1 port and runs --command with "
                    "{url}, {token} and {robot_id} substituted. The robot must accept moves "
                    "between the cells (0..4, 0) of its floor, starting on (0, 0).")
    r.add_argument("--url", help="ws://HOST:PORT/PATH to listen on")
    r.add_argument("--command", help="command starting the robot, e.g. \"fleetgate sim "
                                     "--connect {url} ...\"")
    r.add_argument("--robot-id", type=int, default=0, help="the robot's id (default 0)")
    r.add_argument("--token", help="token the robot must present (default "
                                   "conformance-robot-<id>)")
    r.add_argument("--timeout", type=float, default=20.0,
                   help="seconds to wait for the robot to connect (default 20)")
    _common(r)
    v = modes.add_parser(
        "vda5050", help="check a VDA 5050 vehicle (the checker plays the master control)",
        description="Play a VDA 5050 master control against a vehicle over an MQTT broker "
                    "(docs/vda5050.md, 'Checking a vehicle'): orders with base and horizon, "
                    "order updates and stitching, pause, cancel, rejections, factsheet, the "
                    "last will, and the official schemas of every message it sends. The "
                    "vehicle moves up to three --step along +x of its map from where it "
                    "stands, and back.")
    v.add_argument("--broker", help="mqtt://HOST:PORT or mqtts://HOST:PORT")
    v.add_argument("--manufacturer", help="the vehicle's manufacturer (topic level)")
    v.add_argument("--serial", help="the vehicle's serial number (topic level)")
    v.add_argument("--version", choices=["2.0.0", "2.1.0"], default="2.1.0",
                   help="the protocol version the vehicle speaks (default 2.1.0)")
    v.add_argument("--interface", default="uagv", help="interface name (default uagv)")
    v.add_argument("--step", type=float, default=1.0,
                   help="metres per step of the checks' route (default 1)")
    v.add_argument("--command", help="start the vehicle with this command ({broker}, "
                                     "{manufacturer}, {serial}, {interface}, {version} "
                                     "substituted); enables the last-will check")
    v.add_argument("--schemas", metavar="DIR",
                   help="the official JSON schemas (DIR/<version>/json_schemas; default "
                        "$FLEETGATE_VDA5050_DIR or ../shared/vda5050)")
    v.add_argument("--username", help="broker user name")
    v.add_argument("--password-env", metavar="VAR",
                   help="environment variable holding the broker password")
    v.add_argument("--cafile", help="CA certificate of an mqtts:// broker")
    v.add_argument("--timeout", type=float, default=20.0,
                   help="seconds a step may take (default 20)")
    _common(v)
