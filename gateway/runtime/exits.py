"""Process exit codes and the bad-input error of every ``fleetgate`` command (DESIGN section 3).

The codes every command shares are the project's one set (:mod:`fleetgate.userio.exits`, which
documents them): 0 success, 2 bad input (one-line reason on stderr), 3 no solution within the
limit, 130 interrupted (Ctrl-C), 141 output pipe closed. The gateway adds two of its own:
70 an internal error it cannot go on after (its owner task died), 74 the journal could not be
written or synced.
"""

from __future__ import annotations

import logging
import os

from fleetgate.userio.exits import (
    EPILOG,
    EXIT_BAD_INPUT,
    EXIT_INTERRUPTED,
    EXIT_NO_SOLUTION,
    EXIT_OK,
    UsageError,
)

__all__ = ["EPILOG", "EXIT_BAD_INPUT", "EXIT_INTERRUPTED", "EXIT_JOURNAL", "EXIT_NO_SOLUTION",
           "EXIT_OK", "EXIT_SOFTWARE", "UsageError", "fatal"]

EXIT_SOFTWARE = 70
EXIT_JOURNAL = 74


def fatal(message: str, code: int) -> None:
    """Log ``message`` (one line, critical), flush the logs and end the process with ``code`` at
    once: no event-loop step runs again, so nothing queued for a peer leaves (what a database
    does on a failed WAL write or sync: acknowledge nothing more, and let the supervisor
    restart it)."""
    logging.getLogger("fleetgate").critical(message)
    for handler in logging.getLogger().handlers:
        handler.flush()
    os._exit(code)
