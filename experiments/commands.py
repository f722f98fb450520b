"""``fleetgate`` subcommands of experiments, found via the ``fleetgate.commands`` entry point."""

from __future__ import annotations

import argparse

from experiments import cmd_experiment


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    """Add the ``experiment`` subcommand to the ``fleetgate`` parser."""
    cmd_experiment.register(sub)
