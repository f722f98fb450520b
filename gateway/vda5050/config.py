"""The ``[vda5050]`` section of the gateway's configuration (documented in docs/vda5050.md)."""

from __future__ import annotations

from typing import Annotated

from pydantic import BaseModel, ConfigDict, Field, model_validator

from gateway.vda5050.broker import BrokerConfig
from protocol.vda5050.models import VdaVersion
from protocol.vda5050.nodes import NodeMap
from protocol.vda5050.topics import VehicleTopics, check_level, major_of


class VehicleConfig(BaseModel):
    """One VDA 5050 vehicle and the robot (agent index) it is in plans."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    manufacturer: Annotated[str, Field(min_length=1, max_length=128)]
    serial_number: Annotated[str, Field(min_length=1, max_length=128)]
    robot_id: Annotated[int, Field(ge=0)]
    version: VdaVersion | None = None
    """The protocol version this vehicle speaks (the section's ``version`` if not given)."""


class Vda5050Config(BaseModel):
    """Drive VDA 5050 vehicles through an MQTT broker, beside the websocket robots."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    broker: BrokerConfig = Field(default_factory=BrokerConfig)
    interface_name: Annotated[str, Field(min_length=1, max_length=128)] = "uagv"
    version: VdaVersion = "2.1.0"
    cell_size_m: Annotated[float, Field(gt=0, le=1000)] = 1.0
    map_id: Annotated[str, Field(min_length=1, max_length=128)] = "fleetgate"
    origin_x_m: float = 0.0
    origin_y_m: float = 0.0
    resend_s: Annotated[float, Field(gt=0, le=60)] = 1.0
    """Resend what a vehicle has not acted on (QoS 0 loses messages) after this long."""
    vehicles: list[VehicleConfig] = Field(default_factory=list, max_length=10000)

    @model_validator(mode="after")
    def _unique(self) -> Vda5050Config:
        check_level(self.interface_name, "interface_name")
        robots = [v.robot_id for v in self.vehicles]
        if len(set(robots)) != len(robots):
            raise ValueError("two vehicles have the same robot_id")
        names = [(v.manufacturer, v.serial_number) for v in self.vehicles]
        if len(set(names)) != len(names):
            raise ValueError("two vehicles have the same manufacturer and serial_number")
        for v in self.vehicles:
            self.topics(v)  # ValueError for a name that cannot be a topic level
        return self

    def nodes(self) -> NodeMap:
        """The grid-to-node mapping."""
        return NodeMap(cell_m=self.cell_size_m, map_id=self.map_id, origin_x=self.origin_x_m,
                       origin_y=self.origin_y_m)

    def version_of(self, vehicle: VehicleConfig) -> VdaVersion:
        """The protocol version ``vehicle`` speaks."""
        return vehicle.version or self.version

    def topics(self, vehicle: VehicleConfig) -> VehicleTopics:
        """The topics of ``vehicle``."""
        return VehicleTopics(self.interface_name, major_of(self.version_of(vehicle)),
                             vehicle.manufacturer, vehicle.serial_number)
