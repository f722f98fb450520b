"""Process-wide garbage-collector tuning for the length of a run: the process driver's job.

The plan, ADG, monitor and connections live as long as the run: they are moved out of the
cyclic collector's reach, or its full passes over a large fleet's objects stall the owner task
(~150 ms at 2,000 robots). Only what exists when the run starts is frozen; what the run
allocates later is freed by reference counting. With the default thresholds the collector ran
every 700 allocations, ~25 % of the gateway's CPU and 30-60 ms pauses at 2,000 robots.

A one-shot run (:func:`pause_for_run`) has no cyclic collection at all until it is complete:
its hot path makes no reference cycles (a 5,000-robot run of 148,000 actions left 0
unreachable objects for the collection at its end), so a pass during it found nothing and only
stalled the owner task, for longer the larger the fleet: every object allocated since the last
pass and still alive is traversed (the robots' held actions, the connections' receive
coroutines, the id caches: 130,000-280,000 objects, young passes of 110-290 ms at 5,000
robots, one every 10-20 s, each a backlog that every finish behind it waits out). A one-shot run
is bounded by its plan, and whatever cycles an operator's requests leave meanwhile are
collected once it is complete; an operator's pause, which may last hours, has the collector
back until the run resumes (the gateway's status listener).

A lifelong gateway is tuned from its start (:func:`tune_for_run`: its shift's task pool takes a
WMS's tasks before the shift starts, and a shift has no end to wait for), and so is a worker
process (:mod:`~gateway.server.workers.worker`) once it listens: they keep young passes, but
rare ones (:data:`GC_THRESHOLDS`), except that the owner pauses its workers' collectors for a
one-shot run as it does its own (their young passes, 35-128 ms at 5,000 robots, stall every
robot of the worker; a closed connection leaves a cycle of a few objects, collected after the
run). The tuning lasts for the run only: a collection first, so that
no garbage of an earlier run is frozen and a gateway serving many runs does not grow; the
defaults come back when the run is complete.
"""

from __future__ import annotations

import gc

GC_THRESHOLDS = (100_000, 50, 100)
"""The process's garbage-collector thresholds once a run starts (Python's default: 700, 10,
10): a young-generation pass after 100,000 net new container objects instead of 700."""
GC_DEFAULT_THRESHOLDS = gc.get_threshold()
"""The thresholds restored when a run is complete."""


def freeze_startup() -> None:
    """Freeze what the process holds as a one-shot gateway starts (its modules, app and
    compiled kernels: ~150,000 objects that live as long as it does), without a collection
    (any garbage of the imports is kept until a run is complete): the collection that begins
    a run then goes over what came after (the plan, the connections) instead of these again,
    ~0.1 s of the owner task. :func:`restore_defaults` unfreezes them with the rest."""
    gc.freeze()


def tune_for_run() -> None:
    """Collect, freeze what exists, and collect rarely from now on."""
    gc.collect()
    gc.freeze()
    gc.set_threshold(*GC_THRESHOLDS)


def pause_for_run() -> None:
    """Collect, freeze what exists, and collect nothing more until :func:`restore_defaults`
    (a one-shot run: see the module docstring)."""
    tune_for_run()
    gc.disable()


def end_pause() -> None:
    """Undo :func:`pause_for_run` in a process that stays tuned (a worker process between
    one-shot runs): collect what the run left, then rare passes again."""
    restore_defaults()
    tune_for_run()


def restore_defaults() -> None:
    """Undo :func:`tune_for_run` or :func:`pause_for_run`."""
    gc.unfreeze()
    gc.set_threshold(*GC_DEFAULT_THRESHOLDS)
    gc.enable()
