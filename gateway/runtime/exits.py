"""Process exit codes and the bad-input error of every ``fleetgate`` command (DESIGN section 3).

Exit codes: 0 success, 2 bad input (one-line reason on stderr), 3 no solution within the limit,
70 an internal error the gateway cannot go on after (its owner task died), 74 the journal
could not be written or synced, 130 interrupted (Ctrl-C).
"""

from __future__ import annotations

import logging
import os

EXIT_OK = 0
EXIT_BAD_INPUT = 2
EXIT_NO_SOLUTION = 3
EXIT_SOFTWARE = 70
EXIT_JOURNAL = 74
EXIT_INTERRUPTED = 130


def fatal(message: str, code: int) -> None:
    """Log ``message`` (one line, critical), flush the logs and end the process with ``code`` at
    once: no event-loop step runs again, so nothing queued for a peer leaves (what a database
    does on a failed WAL write or sync: acknowledge nothing more, and let the supervisor
    restart it)."""
    logging.getLogger("fleetgate").critical(message)
    for handler in logging.getLogger().handlers:
        handler.flush()
    os._exit(code)


class UsageError(Exception):
    """Bad input: the CLI prints ``fleetgate: <message>`` and exits with code 2."""
