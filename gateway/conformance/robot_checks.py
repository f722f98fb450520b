"""placeholder"""
from __future__ import annotations
from dataclasses import dataclass
from gateway.conformance.checklist import Checklist
from gateway.conformance.report import CheckResult

@dataclass
class RobotOptions:
    robot_id: int
    token: str
    listen: str | None
    command: str | None
    connect_timeout_s: float = 20.0

ROBOT_CHECKS: Checklist[RobotOptions] = Checklist()

async def run_robot_checks(options: RobotOptions, only: set[str] | None = None) -> list[CheckResult]:
    return []
