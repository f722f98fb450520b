"""The ``fleetgate`` command.

Gateway subcommands live in :mod:`gateway.commands`; packages the gateway must not import
(``sim_clients``, ``experiments``) contribute theirs through the ``fleetgate.commands``
entry-point group. Exit codes and :class:`UsageError` live in :mod:`gateway.runtime.exits`.
"""

from __future__ import annotations

import argparse
import importlib
import sys
from collections.abc import Callable, Sequence
from importlib.metadata import entry_points

from gateway.runtime.exits import EXIT_BAD_INPUT, UsageError

GATEWAY_COMMANDS: tuple[str, ...] = (
    "gateway.commands.plan",
    "gateway.commands.maps",
    "gateway.commands.serve",
    "gateway.commands.protocol",
)
"""Modules with a ``register(subparsers)`` function, in the order ``--help`` lists them."""

Register = Callable[["argparse._SubParsersAction[argparse.ArgumentParser]"], None]


def _registrars() -> list[Register]:
    found: list[Register] = []
    for name in GATEWAY_COMMANDS:
        found.append(importlib.import_module(name).register)
    for ep in sorted(entry_points(group="fleetgate.commands"), key=lambda e: e.name):
        found.append(ep.load())
    return found


def build_parser() -> argparse.ArgumentParser:
    """The full argument parser, with every registered subcommand."""
    parser = argparse.ArgumentParser(
        prog="fleetgate",
        description="Execute multi-robot plans safely, monitor delays, replan when it pays off.",
    )
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for register in _registrars():
        register(sub)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the console script; returns the process exit code."""
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        code: int = args.func(args)
    except UsageError as exc:
        print(f"fleetgate: {exc}", file=sys.stderr)
        return EXIT_BAD_INPUT
    return code
