"""One master control and one simulated vehicle coupled in virtual time, every message passed
as bytes (as over MQTT) and recorded, so tests can validate all traffic against the schemas."""

from __future__ import annotations

import itertools
from collections.abc import Sequence
from dataclasses import dataclass, field

from protocol.messages import HEADINGS, Action, Pose, action_id
from protocol.vda5050.master import ErrandFailed, LinkState, Publish, Report, VehicleMaster
from protocol.vda5050.models import Factsheet, State, VdaVersion, dump, parse
from protocol.vda5050.nodes import THETA, NodeMap
from protocol.vda5050.topics import VehicleTopics
from sim_clients.vda_vehicle import VdaVehicle

Step = tuple[int, int, int]
"""A plan pose ``(x, y, heading)``."""


def actions_of(path: Sequence[Step], plan: int = 0, robot: int = 0) -> list[Action]:
    """The gateway's actions of a turning-model path."""
    return [Action(msg_id=f"m{i}", seq=i, action_id=action_id(plan, robot, i), sequence=i,
                   src=Pose(cell=(a[0], a[1]), heading=HEADINGS[a[2]]),
                   dst=Pose(cell=(b[0], b[1]), heading=HEADINGS[b[2]]), duration_ms=1000.0)
            for i, (a, b) in enumerate(itertools.pairwise(path))]


@dataclass
class Loop:
    """Master and vehicle; :meth:`run` advances virtual time, delivering every message."""

    version: VdaVersion
    start: Step
    drop: set[int] = field(default_factory=set)  # indexes of master publishes to lose
    now: float = 1_700_000_000.0
    traffic: list[tuple[str, bytes]] = field(default_factory=list)
    reports: list[Report] = field(default_factory=list)
    report_times: list[float] = field(default_factory=list)
    links: list[LinkState] = field(default_factory=list)
    failed: list[ErrandFailed] = field(default_factory=list)

    def __post_init__(self) -> None:
        topics = VehicleTopics("uagv", "v2", "fleetgate", "sim0")
        nodes = NodeMap(cell_m=1.0, map_id="lab")
        self.master = VehicleMaster(topics, self.version, nodes)
        self.vehicle = VdaVehicle(topics, self.version, nodes, (self.start[0], self.start[1]),
                                  THETA[HEADINGS[self.start[2]]])
        self._sent = 0
        for out in self.vehicle.connect(self.now)[1:]:
            self._to_master(out.topic, dump(out.message))

    def _to_master(self, topic: str, payload: bytes) -> None:
        self.traffic.append((topic, payload))
        msg = parse(topic, payload)
        if isinstance(msg, State):
            self.master.receive_state(msg, self.now)
        elif isinstance(msg, Factsheet):
            self.master.receive_factsheet(msg)
        elif topic == "connection":
            self.master.receive_connection(msg)  # type: ignore[arg-type]

    def pump(self) -> None:
        """Deliver until nothing is in flight."""
        while True:
            moved = False
            for effect in self.master.drain():
                moved = True
                if isinstance(effect, Publish):
                    payload = dump(effect.message)
                    self.traffic.append((effect.topic, payload))
                    self._sent += 1
                    if self._sent - 1 not in self.drop:
                        self.vehicle.receive(effect.topic, payload, self.now)
                elif isinstance(effect, Report):
                    self.reports.append(effect)
                    self.report_times.append(self.now)
                elif isinstance(effect, ErrandFailed):
                    self.failed.append(effect)
                else:
                    self.links.append(effect)
            for out in self.vehicle.drain():
                moved = True
                self._to_master(out.topic, dump(out.message))
            if not moved:
                return

    def run(self, until: float) -> None:
        """Advance virtual time to ``until`` (seconds after the start)."""
        end = 1_700_000_000.0 + until
        self.pump()
        while True:
            wake = min(self.vehicle.next_wakeup_s(), self.now + 0.5)
            if wake > end:
                break
            self.now = max(self.now, wake)
            self.vehicle.step(self.now)
            self.master.tick(self.now)
            self.pump()
        self.now = end

    def kinds(self, aid: str) -> list[str]:
        """The report kinds for action ``aid``, in order."""
        return [r.kind for r in self.reports if r.action_id == aid]
