"""A worker process's cyclic collector follows the owner's one-shot runs
(gateway/server/gc_tuning.py): the owner's ``COLLECTOR`` command pauses it for a run and gives
the worker its rare passes back once the run is complete (that the owner's pool sends it for a
run: tests/server/test_workers.py)."""

from __future__ import annotations

import asyncio
import gc
import socket

from gateway.server import gc_tuning
from gateway.server.config import GatewayConfig
from gateway.server.workers.channel import Outbox
from gateway.server.workers.records import COLLECTOR
from gateway.server.workers.worker import Worker


async def test_the_collector_command_pauses_and_resumes_a_workers_collector() -> None:
    ours, theirs = socket.socketpair()
    transport, _ = await asyncio.get_running_loop().create_unix_connection(
        asyncio.Protocol, sock=ours)
    worker = Worker(GatewayConfig(port=0, map=None), Outbox(transport))
    gc_tuning.tune_for_run()  # as a worker is once it listens
    try:
        worker.apply([(COLLECTOR, True)])
        assert not gc.isenabled() and gc.get_freeze_count() > 0
        worker.apply([(COLLECTOR, False)])
        assert gc.isenabled() and gc.get_threshold() == gc_tuning.GC_THRESHOLDS
        assert gc.get_freeze_count() > 0  # tuned again: what exists is frozen
    finally:
        gc_tuning.restore_defaults()
        transport.close()
        theirs.close()

