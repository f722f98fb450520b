"""Imported first by a script (``bench/*.py``): from then on an exception that escapes to the
top, Ctrl-C while the script still imports its libraries included, ends it with one line and
the documented exit code instead of a traceback (:func:`fleetgate.userio.exits.guard`)."""

import sys

from fleetgate.userio.exits import guard

guard(sys.argv[0] or "python")
