"""Prometheus metrics of one gateway (its own registry, so several gateways can coexist)."""

from __future__ import annotations

from collections.abc import Callable

from prometheus_client import CollectorRegistry, Counter, Gauge, Histogram, generate_latest

LATENCY_BUCKETS = (0.0005, 0.001, 0.002, 0.005, 0.01, 0.02, 0.05, 0.1, 0.2, 0.5, 1.0, 2.0)
PLANNER_BUCKETS = (0.005, 0.01, 0.02, 0.05, 0.1, 0.2, 0.5, 1.0, 2.0, 5.0, 10.0, 30.0, 60.0)
TASK_BUCKETS = (5.0, 10.0, 20.0, 30.0, 60.0, 120.0, 300.0, 600.0, 1200.0, 1800.0, 3600.0)
OPEN_STATES = ("queued", "paused", "assigned", "started")
"""Task states of the queue-length gauge (finished tasks are counted, not kept)."""


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
        self.tasks = Gauge("fleetgate_tasks",
                           "Lifelong mode: tasks in each open state now (the queue by state)",
                           ["state"], registry=r)
        self.tasks_finished = Counter("fleetgate_tasks_finished",
                                      "Lifelong mode: tasks finished", registry=r)
        self.task_completion = Histogram(
            "fleetgate_task_completion_seconds",
            "Lifelong mode: from a task's submission to its finish (seconds of the shift's "
            "clock)", buckets=TASK_BUCKETS, registry=r)
        self.task_wait = Histogram(
            "fleetgate_task_wait_seconds",
            "Lifelong mode: each finished task's time without a robot (queued from submission "
            "until a robot took it, spells after a hand-back included; seconds of the shift's "
            "clock)", buckets=TASK_BUCKETS, registry=r)
        self.planner_call = Histogram(
            "fleetgate_planner_call_seconds",
            "Planner calls by purpose (window: a lifelong window; load, replan, shadow: a "
            "one-shot plan), wall seconds (charged seconds under virtual time)", ["purpose"],
            buckets=PLANNER_BUCKETS, registry=r)
        self.journal_commit = Histogram(
            "fleetgate_journal_commit_seconds", "Journal commits (wall seconds)",
            buckets=LATENCY_BUCKETS, registry=r)
        self.finished_pending = 0
        """Finishes applied but not yet added to :attr:`finished` (the owner counts each
        action with a plain ``+= 1``; every read, :meth:`value` and :meth:`render`, adds
        them first: a Prometheus ``inc`` takes a lock, two per action on the owner task)."""
        self.dispatched_pending = 0
        """Dispatches not yet added to :attr:`dispatched` (as :attr:`finished_pending`)."""
        self.task_counts: Callable[[], dict[str, int]] | None = None
        """Lifelong mode: how many tasks are in each state now, read at each :meth:`render`."""
        self.waits: Callable[[], dict[str, float]] | None = None
        """Lifelong mode: the assignment waits' ``p50``, ``p90``, ``p99`` and ``max`` (s),
        read at each :meth:`render`."""

    def _fold(self) -> None:
        """Add the pending counts to their counters."""
        if self.finished_pending:
            self.finished.inc(self.finished_pending)
            self.finished_pending = 0
        if self.dispatched_pending:
            self.dispatched.inc(self.dispatched_pending)
            self.dispatched_pending = 0

    def value(self, sample: str, **labels: str) -> float:
        """A sample's value now (``fleetgate_actions_finished_total``, a labelled one by its
        labels); 0 if it has none yet."""
        self._fold()
        found = self.registry.get_sample_value(sample, labels or None)
        return 0.0 if found is None else found

    def render(self) -> bytes:
        """The Prometheus text exposition of every metric."""
        self._fold()
        if self.task_counts is not None:
            counts = self.task_counts()
            for state in OPEN_STATES:
                self.tasks.labels(state).set(counts.get(state, 0))
        if self.waits is not None:
            for key, value in self.waits().items():
                q = "1" if key == "max" else str(int(key[1:]) / 100)
                self.assignment_wait.labels(q).set(value)
        return generate_latest(self.registry)
