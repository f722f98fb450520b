"""``fleetgate serve``: run the gateway (websockets + HTTP) until SIGTERM (exit 0) or Ctrl-C
(exit 130)."""

from __future__ import annotations

import argparse
import contextlib
import sys
from pathlib import Path
from typing import TYPE_CHECKING

from gateway.runtime.exits import UsageError

if TYPE_CHECKING:
    from gateway.server.config import GatewayConfig


async def _serve(config: GatewayConfig, fresh: bool) -> int:
    from fleetgate.userio.signals import StopSignals
    from gateway.server.gateway import Gateway

    stop = StopSignals()
    async with Gateway(config, fresh=fresh) as gateway, contextlib.AsyncExitStack() as vda:
        port = await gateway.listen()
        s = "s" if config.tls is not None else ""
        print(f"fleetgate gateway on ws{s}://{config.host}:{port}/ws "
              f"(GUI http{s}://{config.host}:{port}/, metrics /metrics, probes /healthz "
              f"/readyz)", file=sys.stderr, flush=True)
        if config.vda5050 is not None:
            from gateway.vda5050.transport import VdaTransport

            await vda.enter_async_context(VdaTransport(gateway, config.vda5050))
            print(f"VDA 5050 master control on {config.vda5050.broker.url} "
                  f"({len(config.vda5050.vehicles)} vehicles)", file=sys.stderr, flush=True)
        await stop.wait()
    return stop.exit_code


def _run(args: argparse.Namespace) -> int:
    import asyncio

    from gateway.server.config import ConfigError, default_journal, load_config
    from gateway.server.logs import configure_logging

    try:
        config = load_config(args.config, host=args.host, port=args.port,
                             log_level=args.log_level, log_format=args.log_format,
                             workers=args.workers)
    except ConfigError as exc:
        raise UsageError(str(exc)) from None
    if args.no_journal:
        if args.journal is not None or args.fresh:
            raise UsageError("--no-journal excludes --journal and --fresh")
        config = config.model_copy(update={"journal": None})
    elif args.journal is not None:
        config = config.model_copy(update={"journal": Path(args.journal)})
    elif config.journal is None:
        config = config.model_copy(update={"journal": default_journal()})
    try:
        configure_logging(config.log_level, config.log_format, config.log_file)
    except OSError as exc:
        raise UsageError(f"cannot write the log file {config.log_file}: {exc.strerror}"
                         ) from None
    try:
        return asyncio.run(_serve(config, args.fresh))
    except ValueError as exc:  # the configured instance cannot be loaded, no MQTT broker
        raise UsageError(str(exc)) from None
    except OSError as exc:
        raise UsageError(f"cannot listen on {config.host}:{config.port}: {exc.strerror}"
                         ) from None


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    """Add ``fleetgate serve``."""
    parser = sub.add_parser(
        "serve", help="run the gateway for real robots",
        description="Run the fleetgate gateway: robots, operators and the world connect over "
                    "websockets (ws://HOST:PORT/ws, token in 'Authorization: Bearer' or "
                    "?token=); /metrics, /healthz and the GUI are served on the same port. "
                    "Settings: --config FILE (.json/.toml), then FLEETGATE_* variables "
                    "(nested with __, e.g. FLEETGATE_TOKENS__OPERATORS='[\"x\"]'), then "
                    "these options.")
    parser.add_argument("--config", metavar="FILE", help="configuration file (.json or .toml)")
    parser.add_argument("--host", help="address to listen on (default 127.0.0.1)")
    parser.add_argument("--port", type=int, help="port to listen on (default 8080; 0 = any)")
    parser.add_argument("--workers", type=int, metavar="N",
                        help="worker processes that serve the robots' websockets on the same "
                             "port, beside this one (default 0: one process; see "
                             "docs/workers.md)")
    parser.add_argument("--journal", metavar="FILE",
                        help="the run journal (SQLite; default: journal.sqlite in the state "
                             "directory, $STATE_DIRECTORY under systemd): a restart resumes "
                             "the journaled run where it stopped")
    parser.add_argument("--no-journal", action="store_true",
                        help="journal nothing (a restart loses the run)")
    parser.add_argument("--fresh", action="store_true",
                        help="abandon the journaled run, if any, and start afresh (the only "
                             "way a restart does not resume it)")
    parser.add_argument("--log-level", choices=["DEBUG", "INFO", "WARNING", "ERROR"])
    parser.add_argument("--log-format", choices=["text", "json"],
                        help="log lines on stderr (or log_file): readable text (default) or "
                             "JSON objects")
    parser.set_defaults(func=_run)
