"""A one-shot gateway loads the monitor's compiled kernel and freezes its startup heap as it
starts, not at its first run."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]

# in a fresh process: numba's dispatcher is process-wide, and an earlier test may have loaded it
_SCRIPT = """
import asyncio
import gc
from gateway.execution.oneshot.monitor_kernel import propagate
from gateway.server.config import GatewayConfig
from gateway.server.gateway import Gateway

async def main() -> None:
    before = len(propagate.signatures), gc.get_freeze_count()
    async with Gateway(GatewayConfig(port=0, map=None, log_level="WARNING")) as gw:
        print(*before, len(propagate.signatures), gc.get_freeze_count() > 100_000,
              gc.isenabled(), gw.status)

asyncio.run(main())
"""


def test_a_one_shot_gateway_loads_the_monitors_kernel_and_freezes_its_heap_as_it_starts(
) -> None:
    out = subprocess.run([sys.executable, "-c", _SCRIPT], cwd=ROOT, capture_output=True,
                         text=True, timeout=300, check=True).stdout.split()
    # no run yet; the kernel of every run's argument types loaded, what the process holds
    # frozen (a run's first collection skips it), and the collector still on until a run
    assert out == ["0", "0", "1", "True", "True", "empty"]
