"""``python -m fleetgate``: the ``fleetgate`` command without the console script."""

import sys

from fleetgate.userio.exits import guard

guard("fleetgate")

from gateway.cli import main  # noqa: E402 (after the guard: Ctrl-C while importing)

sys.exit(main())
