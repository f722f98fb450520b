"""``python -m tracecheck FILE.jsonl``: print the findings; exit 1 if any."""

import sys

from fleetgate.userio.exits import guard

guard("tracecheck")

from tracecheck.checker import main  # noqa: E402 (after the guard: Ctrl-C while importing)

sys.exit(main())
