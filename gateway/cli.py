"""The ``fleetgate`` command.

Gateway subcommands live in :mod:`gateway.commands`; packages the gateway must not import
(``sim_clients``, ``experiments``) contribute theirs through the ``fleetgate.commands``
entry-point group. Exit codes (0 success, 2 bad input with a one-line reason on stderr, 3 no
solution within the limit, 130 interrupted, 141 output pipe closed) and how a command ends
(one line, never a traceback) live in :mod:`fleetgate.userio.exits`, shared with every script.

Building the parser imports only the command modules' registration code: each command imports
what it needs (numpy, pydantic, matplotlib...) when it runs, so ``--help`` and the first line
of every command come at once.
"""

from __future__ import annotations

import argparse
import importlib
from collections.abc import Callable, Sequence
from importlib.metadata import entry_points
from typing import Any

from fleetgate.userio.exits import CommandParser, call

GATEWAY_COMMANDS: tuple[str, ...] = (
    "gateway.commands.plan",
    "gateway.commands.maps",
    "gateway.commands.serve",
    "gateway.commands.protocol",
    "gateway.commands.conformance",
)
"""Modules with a ``register(subparsers)`` function, in the order ``--help`` lists them."""

class StrictParser(CommandParser):
    """A parser that rejects unknown arguments itself, so a mistyped option of a subcommand
    gets that subcommand's usage line, not the top-level one. Options are never abbreviated
    (a typo that happens to be a prefix of an option must not run the command)."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        kwargs.setdefault("allow_abbrev", False)
        super().__init__(*args, **kwargs)

    def parse_known_args(  # type: ignore[override]
            self, args: Sequence[str] | None = None, namespace: argparse.Namespace | None = None,
    ) -> tuple[argparse.Namespace, list[str]]:
        """Parse ``args``; any argument left over is an error of this parser."""
        parsed, extras = super().parse_known_args(args, namespace)
        if extras:
            self.error(f"unrecognized arguments: {' '.join(extras)}")
        return parsed, extras


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
    parser = StrictParser(
        prog="fleetgate",
        description="Execute multi-robot plans safely, monitor delays, replan when it pays off.",
    )
    parser.add_argument("--version", action="version", version=f"%(prog)s {_version()}")
    sub: argparse._SubParsersAction[argparse.ArgumentParser] = parser.add_subparsers(
        dest="command", required=True, metavar="COMMAND", parser_class=StrictParser)
    for register in _registrars():
        register(sub)
    return parser


def _version() -> str:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("fleetgate")
    except PackageNotFoundError:  # run from a source tree that was never installed
        return "unknown"


def _main(argv: Sequence[str] | None) -> int:
    args = build_parser().parse_args(argv)
    code: int = args.func(args)
    return code


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the console script; returns the process exit code (Ctrl-C, a closed
    pipe, an unwritable output: one line and the documented code, see
    :mod:`fleetgate.userio.exits`)."""
    return call("fleetgate", _main, argv)
