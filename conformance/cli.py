"""``fleetgate conformance gateway|robot``: arguments, running a checklist, printing results.

Exit codes: 0 every required check passed, 1 a required check failed, 2 bad invocation or a
target that cannot be reached (one line on stderr, never a traceback).
"""

from __future__ import annotations

import argparse
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
                      operator_token=args.operator_token, map=args.map, cafile=args.cafile)
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


def run(args: argparse.Namespace) -> int:
    """Run the chosen mode; UsageProblem becomes a one-line error and exit code 2 (Ctrl-C,
    a closed pipe and an unwritable output end as every command's: :mod:`fleetgate.userio`)."""
    try:
        return int(_gateway(args) if args.mode == "gateway" else _robot(args))
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
