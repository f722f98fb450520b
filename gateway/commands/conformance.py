"""``fleetgate conformance gateway|robot``: check an implementation against the robot protocol."""

from __future__ import annotations

import argparse

from conformance.cli import add_arguments, run


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    """Add ``fleetgate conformance``."""
    parser = sub.add_parser(
        "conformance", help="check a gateway or a robot against the protocol",
        description="Check a gateway or a robot implementation against the fleetgate robot "
                    "protocol (docs/protocol.md). Exit code 0: every required check "
                    "passed; 1: a required check failed; 2: bad invocation or unreachable "
                    "target.")
    add_arguments(parser)
    parser.set_defaults(func=run)
