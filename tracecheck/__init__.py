"""The independent trace checker (DESIGN section 3): it imports nothing of fleetgate.

Run it as ``python -m tracecheck FILE.jsonl``. :mod:`tracecheck.lorr` checks LoRR output the
same way.
"""

from tracecheck.checker import build_graph, check_trace, main, slack_series
from tracecheck.reader import iter_trace, read_trace

__all__ = ["build_graph", "check_trace", "iter_trace", "main", "read_trace", "slack_series"]
