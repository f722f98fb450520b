"""Process exit codes and the bad-input error of every ``fleetgate`` command (DESIGN section 3).

Exit codes: 0 success, 2 bad input (one-line reason on stderr), 3 no solution within the limit,
130 interrupted (Ctrl-C).
"""

from __future__ import annotations

EXIT_OK = 0
EXIT_BAD_INPUT = 2
EXIT_NO_SOLUTION = 3
EXIT_INTERRUPTED = 130


class UsageError(Exception):
    """Bad input: the CLI prints ``fleetgate: <message>`` and exits with code 2."""
