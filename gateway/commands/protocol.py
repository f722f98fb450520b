"""``fleetgate protocol schema``: write the JSON Schema of the wire protocol."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from gateway.runtime.exits import EXIT_OK, UsageError


def _schema(args: argparse.Namespace) -> int:
    if args.markdown is not None:
        return _markdown(Path(args.markdown))
    from protocol import json_schema

    text = json.dumps(json_schema(), indent=2, sort_keys=True) + "\n"
    if args.output is None:
        sys.stdout.write(text)
        return EXIT_OK
    try:
        Path(args.output).write_text(text)
    except OSError as exc:
        raise UsageError(f"cannot write {args.output}: {exc.strerror}") from None
    return EXIT_OK


def _markdown(path: Path) -> int:
    from conformance.doc import StaleDocument, render

    try:
        path.write_text(render(path.read_text()))
    except OSError as exc:
        raise UsageError(f"cannot update {path}: {exc.strerror}") from None
    except StaleDocument as exc:
        raise UsageError(f"{path}: {exc}") from None
    return EXIT_OK


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    """Add ``fleetgate protocol`` (with its ``schema`` subcommand)."""
    parser = sub.add_parser("protocol", help="the robot/operator wire protocol",
                            description="Tools for the fleetgate wire protocol (v1).")
    inner = parser.add_subparsers(dest="protocol_command", required=True, metavar="SUBCOMMAND")
    schema = inner.add_parser("schema", help="write the JSON Schema of every message",
                              description="Write the JSON Schema (draft 2020-12) of protocol "
                                          "v1 to FILE or standard output.")
    schema.add_argument("-o", "--output", metavar="FILE", help="write here instead of stdout")
    schema.add_argument("--markdown", metavar="FILE",
                        help="instead, rewrite the generated message table and schema blocks "
                             "of FILE (docs/protocol.md)")
    schema.set_defaults(func=_schema)
