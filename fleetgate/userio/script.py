"""Imported first by a script (``bench/*.py``, a package's ``__main__``): from then on an
exception that escapes to the top, Ctrl-C while the script still imports its libraries
included, ends it with one line and the documented exit code instead of a traceback
(:func:`fleetgate.userio.exits.guard`)."""

import sys
from pathlib import Path

from fleetgate.userio.exits import guard


def _prog(argv0: str) -> str:
    path = Path(argv0)
    if path.name == "__main__.py":
        return path.parent.name  # python -m PACKAGE
    return path.name if path.is_absolute() else argv0  # a console script; bench/x.py


guard(_prog(sys.argv[0]) if sys.argv and sys.argv[0] else "python")
