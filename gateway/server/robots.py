"""What the gateway knows about each robot: its connection, pose and the actions it holds."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Literal

from gateway.server.session import Session
from protocol import Pose
from protocol.messages import RobotActivity


@dataclass
class Held:
    """An action a robot holds: dispatched, not finished or cancelled."""

    fields: dict[str, Any]
    phase: Literal["dispatched", "running", "blocked"] = "dispatched"
    acked: bool = False
    cancel: bool = False


@dataclass
class RobotRecord:
    """What the gateway knows about one robot."""

    session: Session | None = None
    pose: Pose | None = None
    held: dict[str, Held] = field(default_factory=dict)
    applied: dict[str, str] = field(default_factory=dict)  # action id -> "finished"/"cancelled"
    next_index: int = 0  # actions of the current plan finished

    def activity(self) -> RobotActivity:
        """What the robot is doing, as far as the gateway knows."""
        if self.session is None:
            return "disconnected"
        for h in self.held.values():
            return "received" if h.phase == "dispatched" else h.phase
        return "idle"
