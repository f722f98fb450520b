"""Process-wide garbage-collector tuning for the length of a run: the process driver's job.

The plan, ADG, monitor and connections live as long as the run: they are moved out of the
cyclic collector's reach, or its full passes over a large fleet's objects stall the owner task
(~150 ms at 2,000 robots). Only what exists when the run starts is frozen; what the run
allocates later is collected, but rarely (:data:`GC_THRESHOLDS`): nearly all of it is freed by
reference counting, and with the default thresholds the collector ran every 700 allocations,
~25 % of the gateway's CPU and 30-60 ms pauses at 2,000 robots. The tuning lasts for the run
only: a collection first, so that no garbage of an earlier run is frozen and a gateway serving
many runs does not grow; the defaults come back when the run is complete. A lifelong gateway
is tuned from its start too (its shift's task pool takes a WMS's tasks before the shift
starts), and so is a worker process (:mod:`~gateway.server.workers.worker`) once it listens:
its connections' objects are freed by reference counting too.
"""

from __future__ import annotations

import gc

GC_THRESHOLDS = (100_000, 50, 100)
"""The process's garbage-collector thresholds once a run starts (Python's default: 700, 10,
10): a young-generation pass after 100,000 net new container objects instead of 700."""
GC_DEFAULT_THRESHOLDS = gc.get_threshold()
"""The thresholds restored when a run is complete."""


def tune_for_run() -> None:
    """Collect, freeze what exists, and collect rarely from now on."""
    gc.collect()
    gc.freeze()
    gc.set_threshold(*GC_THRESHOLDS)


def restore_defaults() -> None:
    """Undo :func:`tune_for_run`."""
    gc.unfreeze()
    gc.set_threshold(*GC_DEFAULT_THRESHOLDS)
