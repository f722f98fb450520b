"""``python -m fleetgate``: the ``fleetgate`` command without the console script."""

import sys

from gateway.cli import main

sys.exit(main())
