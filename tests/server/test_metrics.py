"""The owner's pending action counts reach the Prometheus counters on every read."""

from __future__ import annotations

from gateway.server.metrics import Metrics


def test_pending_counts_are_added_before_every_read() -> None:
    m = Metrics()
    m.finished_pending += 3
    m.dispatched_pending += 2
    assert m.value("fleetgate_actions_finished_total") == 3.0
    assert m.finished_pending == 0
    m.finished_pending += 1
    text = m.render().decode()
    assert "fleetgate_actions_finished_total 4.0" in text
    assert "fleetgate_actions_dispatched_total 2.0" in text
    assert m.value("fleetgate_actions_dispatched_total") == 2.0  # folded once, not twice
