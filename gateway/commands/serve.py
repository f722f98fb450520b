"""``fleetgate serve``: run the gateway (websockets + HTTP) until interrupted."""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import signal
import sys

from gateway.cli import EXIT_OK, UsageError
from gateway.server.config import ConfigError, GatewayConfig, load_config
from gateway.server.gateway import Gateway
from gateway.server.logs import configure_logging


async def _serve(config: GatewayConfig) -> None:
    stop = asyncio.Event()
    loop = asyncio.get_running_loop()
    for sig in (signal.SIGINT, signal.SIGTERM):
        with contextlib.suppress(NotImplementedError):
            loop.add_signal_handler(sig, stop.set)
    async with Gateway(config) as gateway:
        port = await gateway.listen()
        s = "s" if config.tls is not None else ""
        print(f"fleetgate gateway on ws{s}://{config.host}:{port}/ws "
              f"(GUI http{s}://{config.host}:{port}/, metrics /metrics, probes /healthz "
              f"/readyz)", file=sys.stderr, flush=True)
        await stop.wait()


def _run(args: argparse.Namespace) -> int:
    try:
        config = load_config(args.config, host=args.host, port=args.port,
                             log_level=args.log_level)
    except ConfigError as exc:
        raise UsageError(str(exc)) from None
    configure_logging(config.log_level)
    try:
        asyncio.run(_serve(config))
    except ValueError as exc:  # the configured instance cannot be loaded
        raise UsageError(str(exc)) from None
    except OSError as exc:
        raise UsageError(f"cannot listen on {config.host}:{config.port}: {exc.strerror}"
                         ) from None
    return EXIT_OK


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
    parser.add_argument("--log-level", choices=["DEBUG", "INFO", "WARNING", "ERROR"])
    parser.set_defaults(func=_run)
