"""The run contract holds for both runs: a one-shot run and a lifelong shift pass the same
suite (:func:`tests.server.run_contract.check_run`) through a real gateway in virtual time."""

from __future__ import annotations

import pytest

from gateway.server.config import GatewayConfig, LifelongSettings
from tests.server.run_contract import Make, RunSetup, check_run
from tests.server.test_journal import lanes


def one_shot() -> RunSetup:
    """Four robots crossing a 20-cell grid in lanes (long enough to pause and resume)."""
    config = GatewayConfig(port=0, map=None, autostart=False, policy="none",
                           log_level="WARNING")
    return RunSetup(config, 4, lanes(4, 20))


def lifelong() -> RunSetup:
    """A six-robot warehouse shift (its planner charged 120 ms a call)."""
    config = GatewayConfig(port=0, map=None, autostart=False, log_level="WARNING",
                           lifelong=LifelongSettings(robots=6, warehouse=(2, 3)))
    return RunSetup(config, 6)


@pytest.mark.parametrize("make", [one_shot, lifelong], ids=["one-shot", "lifelong"])
def test_run_contract(make: Make) -> None:
    check_run(make)
