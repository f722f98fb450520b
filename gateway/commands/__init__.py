"""Subcommands of the ``fleetgate`` CLI that belong to the gateway; one module each.

Each module exposes ``register(subparsers)`` that adds its parser and sets ``func`` to a
callable taking the parsed namespace and returning the exit code.
"""
