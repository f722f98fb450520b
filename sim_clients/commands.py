"""``fleetgate`` subcommands of sim_clients, found via the ``fleetgate.commands`` entry point."""

from __future__ import annotations

import argparse
import importlib

SIM_COMMANDS: tuple[str, ...] = (
    "sim_clients.cmd_simulate",
    "sim_clients.cmd_sim",
    "sim_clients.cmd_demo",
    "sim_clients.cmd_lifelong",
)


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    """Add every sim_clients subcommand to the ``fleetgate`` parser."""
    for name in SIM_COMMANDS:
        importlib.import_module(name).register(sub)
