"""Process exit codes and the bad-input error of every ``fleetgate`` command (DESIGN section 3).

They are the project's one set (:mod:`fleetgate.userio.exits`, which also documents them):
0 success, 2 bad input (one-line reason on stderr), 3 no solution within the limit, 130 interrupted
(Ctrl-C), 141 output pipe closed.
"""

from __future__ import annotations

from fleetgate.userio.exits import (
    EPILOG,
    EXIT_BAD_INPUT,
    EXIT_INTERRUPTED,
    EXIT_NO_SOLUTION,
    EXIT_OK,
    UsageError,
)

__all__ = ["EPILOG", "EXIT_BAD_INPUT", "EXIT_INTERRUPTED", "EXIT_NO_SOLUTION", "EXIT_OK",
           "UsageError"]
