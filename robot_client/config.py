"""Settings of a robot: gateway, identity, devices, floor grid, camera and controller.

Sources, highest priority first: command-line options (``--robot-id 3``), environment
variables (``FLEETGATE_ROBOT_ROBOT_ID=3``), a TOML file (``--config robot.toml`` or
``FLEETGATE_ROBOT_CONFIG``), then the defaults below.
"""

from __future__ import annotations

import os
import ssl
from pathlib import Path
from typing import Any, Literal

from pydantic import Field, SecretStr, ValidationError
from pydantic_settings import (
    BaseSettings,
    CliSettingsSource,
    PydanticBaseSettingsSource,
    SettingsConfigDict,
    TomlConfigSettingsSource,
)

from fleetgate.userio.exits import CommandParser
from protocol.messages import Heading
from protocol.tls import client_context
from robot_client.apriltag_localiser import DownwardCamera
from robot_client.floor import FloorGrid
from robot_client.runner import RunnerParams

ENV_PREFIX = "FLEETGATE_ROBOT_"


class RobotSettings(BaseSettings):
    """Everything a robot needs to know to join the fleet."""

    model_config = SettingsConfigDict(
        env_prefix=ENV_PREFIX, extra="forbid", cli_prog_name="fleetgate-robot",
        cli_kebab_case=True, cli_implicit_flags="toggle")

    config: str = Field("", description="TOML file with these settings (see deploy/robot.md;"
                                        " read before the others)")
    log_level: Literal["DEBUG", "INFO", "WARNING", "ERROR"] = Field(
        "INFO", description="log level of the robot's log lines on stderr")
    gateway_url: str = Field("ws://127.0.0.1:8080/ws", description="gateway websocket URL")
    robot_id: int = Field(ge=0, description="this robot's agent index in the plan")
    token: SecretStr = Field(description="per-robot token (sent as 'Authorization: Bearer')")
    ca_file: Path | None = Field(None, description="wss://: PEM CA that signed the gateway's "
                                 "certificate (default: the system's CAs)")
    client_cert: Path | None = Field(None, description="wss://: PEM client certificate issued "
                                     "to fleetgate:robot:<robot_id> (mutual TLS)")
    client_key: Path | None = Field(None, description="its PEM key (if not in client_cert)")
    serial_port: str = Field("/dev/kobuki", description="Kobuki base serial device")
    camera_index: int = Field(0, ge=0, description="cv2.VideoCapture index of the camera")
    no_camera: bool = Field(False, description="run on odometry only (no camera)")

    grid_width: int = Field(ge=1, description="tag grid columns")
    grid_height: int = Field(ge=1, description="tag grid rows")
    cell_m: float = Field(0.4, gt=0, description="cell side (m)")
    tag_size_m: float = Field(0.12, gt=0, description="side of a tag's black square (m)")
    start_x: int = Field(0, ge=0, description="start cell column (until a tag is seen)")
    start_y: int = Field(0, ge=0, description="start cell row (until a tag is seen)")
    start_heading: Heading = Field("E", description="start heading (until a tag is seen)")

    camera_width_px: int = Field(640, gt=0)
    camera_height_px: int = Field(480, gt=0)
    camera_ppm: float = Field(800.0, gt=0, description="floor pixels per metre in the image")
    camera_forward_m: float = Field(0.25, description="image centre ahead of the robot (m)")
    camera_period_ms: float = Field(100.0, gt=0, description="time between frames (ms)")
    tag_gain: float = Field(1.0, gt=0, le=1, description="1 = snap to the tag fix")

    control_period_ms: float = Field(20.0, gt=0, description="control tick (ms)")
    max_speed_m_s: float = Field(0.2, gt=0, le=0.7)
    max_turn_rad_s: float = Field(1.2, gt=0, le=3.0)
    linear_gain: float = Field(1.5, gt=0, description="forward speed per metre to go (1/s)")
    bumper_pause_ms: float = Field(5000.0, ge=0)

    reconnect_min_s: float = Field(0.5, gt=0, description="first reconnect delay")
    reconnect_max_s: float = Field(10.0, gt=0, description="largest reconnect delay")
    ping_interval_s: float = Field(2.0, gt=0, description="websocket ping period")
    ping_timeout_s: float = Field(3.0, gt=0, description="link declared lost after this")

    def ssl_context(self) -> ssl.SSLContext | None:
        """The TLS settings of a ``wss://`` gateway URL (None for ``ws://``); OSError or
        ssl.SSLError if the CA, certificate or key cannot be loaded."""
        if not self.gateway_url.startswith("wss://"):
            return None
        return client_context(self.ca_file, self.client_cert, self.client_key)

    def floor(self) -> FloorGrid:
        """The tag grid."""
        return FloorGrid(self.grid_width, self.grid_height, self.cell_m, self.tag_size_m)

    def camera(self) -> DownwardCamera:
        """The camera model."""
        return DownwardCamera(self.camera_width_px, self.camera_height_px, self.camera_ppm,
                              self.camera_forward_m)

    def runner_params(self) -> RunnerParams:
        """The controller's parameters."""
        return RunnerParams(max_speed_m_s=self.max_speed_m_s, max_turn_rad_s=self.max_turn_rad_s,
                            linear_gain=self.linear_gain, bumper_pause_ms=self.bumper_pause_ms)


_METAVARS = {"SecretStr": "TOKEN", "{Path,null}": "FILE", "Path": "FILE", "str": "TEXT",
             "int": "N", "float": "NUMBER"}
"""Placeholders in ``--help`` for pydantic's type names (``--token TOKEN``, not SecretStr)."""


class _Cli(CliSettingsSource[Any]):
    """The command line of the settings, with placeholders a user reads (:data:`_METAVARS`)."""

    def _metavar_format(self, obj: Any) -> str:
        text = super()._metavar_format(obj)
        return _METAVARS.get(text, text)

    def _help_format(self, *args: Any, **kwargs: Any) -> str:
        text: str = super()._help_format(*args, **kwargs)
        return text.replace(f"(default: {self.cli_parse_none_str})", "(default: none)")


class ConfigError(ValueError):
    """The settings are incomplete or wrong (one-line reason)."""


def load_settings(argv: list[str] | None = None, config_file: str | Path | None = None,
                  **overrides: Any) -> RobotSettings:
    """Settings from ``argv`` (None: no command line), env, the TOML file and ``overrides``.

    ``overrides`` (for tests and embedding) take precedence over everything.
    """
    path = config_file or os.environ.get(ENV_PREFIX + "CONFIG")
    if path is not None and not Path(path).is_file():
        raise ConfigError(f"config file {path} not found")

    class _WithFile(RobotSettings):
        @classmethod
        def settings_customise_sources(
                cls, settings_cls: type[BaseSettings], init_settings: PydanticBaseSettingsSource,
                env_settings: PydanticBaseSettingsSource,
                dotenv_settings: PydanticBaseSettingsSource,
                file_secret_settings: PydanticBaseSettingsSource,
        ) -> tuple[PydanticBaseSettingsSource, ...]:
            sources: tuple[PydanticBaseSettingsSource, ...] = (init_settings, env_settings)
            if path is not None:
                sources += (TomlConfigSettingsSource(settings_cls, toml_file=path),)
            return sources

    try:
        cli: dict[str, Any] = {"_cli_parse_args": False}
        if argv is not None:
            parser = CommandParser(prog="fleetgate-robot",
                                             description=__doc__.splitlines()[0])
            cli = {"_cli_settings_source": _Cli(_WithFile, cli_parse_args=argv,
                                                root_parser=parser)}
        return _WithFile(**cli, **overrides)
    except ValidationError as exc:
        err = exc.errors(include_url=False)[0]
        where = ".".join(str(p) for p in err["loc"])
        raise ConfigError(f"{where}: {err['msg']}") from None
