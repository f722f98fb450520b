"""A real Eclipse Mosquitto broker for the VDA 5050 tests (started on a free loopback port,
stopped after the test); skipped where mosquitto is not installed (scripts/test.sh installs
it)."""

from __future__ import annotations

from collections.abc import Iterator

import pytest

from sim_clients.mosquitto import LocalBroker, MosquittoMissing


@pytest.fixture
def broker_url() -> Iterator[str]:
    """``mqtt://127.0.0.1:PORT`` of a private mosquitto."""
    try:
        broker = LocalBroker()
    except MosquittoMissing as exc:
        pytest.skip(str(exc))
    with broker as url:
        yield url
