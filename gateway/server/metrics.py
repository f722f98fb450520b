"""Prometheus metrics of one gateway (its own registry, so several gateways can coexist)."""

from __future__ import annotations

from collections.abc import Callable

from prometheus_client import CollectorRegistry, Counter, Gauge, Histogram, generate_latest

LATENCY_BUCKETS = (0.0005, 0.001, 0.002, 0.005, 0.01, 0.02, 0.05, 0.1, 0.2, 0.5, 1.0, 2.0)


class Metrics:
    """The gateway's counters, gauges and the finish-to-dispatch latency histogram."""

    def __init__(self) -> None:
        self.registry = CollectorRegistry()
        r = self.registry
        self.connected_robots = Gauge("fleetgate_connected_robots", "Robots connected now",
                                      registry=r)
        self.connections = Gauge("fleetgate_connections", "Connections by role", ["role"],
                                 registry=r)
        self.dispatched = Counter("fleetgate_actions_dispatched", "Actions dispatched",
                                  registry=r)
        self.finished = Counter("fleetgate_actions_finished", "Action finishes applied",
                                registry=r)
        self.latency = Histogram(
            "fleetgate_finish_to_dispatch_seconds",
            "From a finish report received to each dispatch it unlocks being queued",
            buckets=LATENCY_BUCKETS, registry=r)
        self.fleet_slack = Gauge("fleetgate_fleet_slack_ms", "Fleet slack (ms)", registry=r)
        self.replans = Counter("fleetgate_replans", "Replans triggered", registry=r)
        self.queue_depth = Gauge("fleetgate_event_queue_depth", "Events waiting for the owner",
                                 registry=r)
        self.errors = Counter("fleetgate_protocol_errors", "Error replies", ["code"], registry=r)
        self.refused = Counter("fleetgate_handshakes_refused", "Websocket upgrades refused",
                               ["status"], registry=r)
        self.handler_failures = Counter(
            "fleetgate_handler_failures", "Connections closed 1011 by an unexpected error",
            registry=r)
        self.assignment_wait = Gauge(
            "fleetgate_task_assignment_wait_seconds",
            "Lifelong mode: tasks' wait from submission to a robot, over the kept tasks (a "
            "task still queued counts as waiting until now); quantile 1 is the longest",
            ["quantile"], registry=r)
        self.waits: Callable[[], dict[str, float]] | None = None
        """Lifelong mode: the assignment waits' ``p50``, ``p90``, ``p99`` and ``max`` (s),
        read at each :meth:`render`."""

    def render(self) -> bytes:
        """The Prometheus text exposition of every metric."""
        if self.waits is not None:
            for key, value in self.waits().items():
                q = "1" if key == "max" else str(int(key[1:]) / 100)
                self.assignment_wait.labels(q).set(value)
        return generate_latest(self.registry)
