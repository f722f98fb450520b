"""The one exception the execution core raises for input that makes no sense."""

from __future__ import annotations


class ExecutionError(ValueError):
    """An event, plan or query the executor cannot accept; nothing was changed."""
