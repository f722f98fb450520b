"""``python -m tracecheck FILE.jsonl``: print the findings; exit 1 if any."""

import sys

from tracecheck.checker import main

sys.exit(main())
