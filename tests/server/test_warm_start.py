"""A one-shot gateway loads the monitor's compiled kernel as it starts, not at its first run."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]

# in a fresh process: numba's dispatcher is process-wide, and an earlier test may have loaded it
_SCRIPT = """
import asyncio
from gateway.execution.oneshot.monitor_kernel import propagate
from gateway.server.config import GatewayConfig
from gateway.server.gateway import Gateway

async def main() -> None:
    before = len(propagate.signatures)
    async with Gateway(GatewayConfig(port=0, map=None, log_level="WARNING")) as gw:
        print(before, len(propagate.signatures), gw.status)

asyncio.run(main())
"""


def test_a_one_shot_gateway_loads_the_monitors_kernel_as_it_starts() -> None:
    out = subprocess.run([sys.executable, "-c", _SCRIPT], cwd=ROOT, capture_output=True,
                         text=True, timeout=300, check=True).stdout.split()
    assert out == ["0", "1", "empty"]  # no run yet, and the kernel of every run's types loaded
