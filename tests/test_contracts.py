"""One home per shared contract (issue 10): where a second definition must exist on purpose
(the wire protocol and the independent trace checker import nothing of the gateway), it agrees
with the home."""

from __future__ import annotations

from typing import get_args

from gateway.execution.oneshot.policies import AUTONOMOUS_POLICIES, POLICY_NAMES, make_policy
from gateway.execution.params import PAPER
from gateway.execution.trace_records import (
    EVENT_TYPES,
    event_record,
    intruder_record,
    plan_record,
    summary_record,
    trigger_record,
)
from gateway.server.config import GatewayConfig
from protocol.messages import PolicyName as WirePolicyName
from sim_clients.des import SimConfig
from tracecheck import check_trace


def test_the_wire_protocol_names_the_registrys_policies() -> None:
    assert get_args(WirePolicyName) == POLICY_NAMES


def test_the_registry_builds_every_policy_by_its_name() -> None:
    assert set(AUTONOMOUS_POLICIES) == set(POLICY_NAMES) - {"operator"}
    for name in POLICY_NAMES:
        assert make_policy(name, makespan_lb_ms=20_000.0).name == name


def test_gateway_and_simulator_default_to_the_papers_parameters() -> None:
    gateway = GatewayConfig()
    fields = SimConfig.__dataclass_fields__
    assert gateway.threshold_ms == fields["threshold_ms"].default == PAPER.threshold_ms == 2000
    assert gateway.action_ms == fields["action_ms"].default == PAPER.action_ms == 1000
    assert gateway.max_replans == fields["max_replans"].default == PAPER.max_replans == 1


def test_the_checker_knows_every_record_type_the_gateway_writes() -> None:
    records = [plan_record(0.0, 0, [[(0, 0), (1, 0)]]),
               *(event_record(0.0, kind, 0, 0, 0) for kind in EVENT_TYPES),
               trigger_record(0.0, "slack", 0.0), intruder_record(0.0, (2, 0), "on"),
               summary_record(0.0, 0.0)]
    for record in records:
        errors = check_trace([records[0], record]).errors
        assert not any("unknown record type" in e for e in errors), (record, errors)
