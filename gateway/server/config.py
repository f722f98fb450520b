"""Gateway configuration: defaults < config file (JSON or TOML) < FLEETGATE_* env < arguments.

The embedded defaults give a zero-setup loopback demo: 127.0.0.1:8080, the ``lab`` map, demo
tokens (``demo-robot-<id>``, ``demo-operator``, ``demo-world``). Demo tokens are refused on a
non-loopback host unless ``allow_demo_tokens`` is set; so are the example configs' placeholder
tokens (``CHANGE-ME-...``), and plain websockets unless ``allow_plaintext`` is set (a TLS proxy
in front).
"""

from __future__ import annotations

import ipaddress
import os
from pathlib import Path
from typing import Annotated, Any, Literal

from pydantic import (
    AliasChoices,
    BaseModel,
    ConfigDict,
    Field,
    ValidationError,
    model_validator,
)
from pydantic_settings import (
    BaseSettings,
    JsonConfigSettingsSource,
    PydanticBaseSettingsSource,
    SettingsConfigDict,
    TomlConfigSettingsSource,
)

from gateway.execution.oneshot.policies import PolicyName
from gateway.execution.params import PAPER
from gateway.vda5050.config import Vda5050Config

PLACEHOLDER = "CHANGE-ME"
"""What the example configs' tokens contain: refused on a non-loopback host."""


class TokensConfig(BaseModel):
    """Who may connect: bearer token -> role (and robot id for robots)."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    robots: dict[str, int] = Field(default_factory=dict,
                                   description="token -> robot id (agent index)")
    operators: list[str] = Field(default_factory=lambda: ["demo-operator"])
    world: list[str] = Field(default_factory=lambda: ["demo-world"])
    demo_robot_prefix: str | None = "demo-robot-"
    """If set, the token ``<prefix><id>`` authenticates robot ``<id>``."""


class TlsConfig(BaseModel):
    """TLS on the gateway's port (websockets, GUI and HTTP API alike).

    With ``client_ca`` the gateway asks every client for a certificate signed by that CA
    (mutual TLS): a robot must then present one issued to its robot id (SAN URI or CN
    ``fleetgate:robot:<id>``), and may omit its token. Browsers without a certificate can
    still open the GUI unless ``require_client_cert`` refuses them at the TLS handshake.
    """

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    cert: Path = Field(description="PEM certificate chain of the gateway")
    key: Path = Field(description="PEM private key of the gateway")
    client_ca: Path | None = Field(default=None, description="PEM CA of client certificates")
    require_client_cert: bool = False
    """Refuse clients without a certificate at the TLS handshake (operators too)."""


class RobotModel(BaseModel):
    """Expected duration ``t_x`` of each action kind for one kind of robot (ms)."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    move_ms: float = Field(default=PAPER.action_ms, gt=0)
    turn_ms: float = Field(default=PAPER.action_ms, gt=0)
    wait_ms: float = Field(default=PAPER.action_ms, gt=0)


class LifelongSettings(BaseModel):
    """Lifelong mode: ``fleetgate serve`` runs a warehouse shift (tasks, a plan window every
    period appended to a live ADG while the robots move) instead of one plan. The motion
    model is the gateway's ``motion``; t_x of every action is ``action_ms``."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    problem: Path | None = None
    """A LoRR problem (JSON: map, robots' starts, task list); None: ``map``, else a generated
    warehouse."""
    map: str | None = None
    """A MovingAI map (a name or a ``.map`` path; a ``map`` at the top level is taken as this
    one) instead of the generated warehouse: ``robots`` start on free cells drawn with
    ``seed``; its task list (``task_list``) is four two-errand tasks per robot between free
    cells."""
    robots: int = Field(default=20, ge=1)
    """Robots of the generated warehouse or of ``map`` (a problem brings its own)."""
    warehouse: tuple[int, int] = (4, 6)
    """Shelf blocks (x, y) of the generated warehouse; (13, 25) is about 10,000 free cells."""
    seed: int = 0
    """Seed of the generated warehouse and of the planner's tie-breaks."""
    scheduler: Literal["shortest"] = "shortest"
    max_wait_ms: float | None = Field(default=45_000.0, gt=0)
    """Fairness bound: a task that has waited this long for a robot goes before the tasks of
    its priority that have not, and waiting tasks age towards it (None: no bound; then a far
    or long task can wait a whole shift while nearer ones keep coming)."""
    planner: Literal["pibt"] = "pibt"
    """The windowed planner: 1-robust PIBT (gateway/planning/pibt.py)."""
    period_ms: float = Field(default=1000.0, gt=0)
    """Time between planning calls (LoRR's planning period)."""
    window: int = Field(default=0, ge=0, validation_alias=AliasChoices("window", "horizon"))
    """Timesteps planned per call, the planning horizon (also ``horizon``; 0: enough for a
    period, ceil(period_ms / action_ms))."""
    reveal: float | None = Field(default=None, gt=0)
    """Tasks kept revealed per robot (None: the problem's numTasksReveal)."""
    task_list: bool = True
    """Reveal the problem's task list as the LoRR Start-Kit does (tasks submitted through
    the API are added to the same pool)."""
    threshold_ms: float | None = Field(default=PAPER.threshold_ms, ge=0)
    """Fleet-slack threshold of the early planning call (None: no slack trigger)."""
    snapshot_segments: int = Field(default=60, ge=0)
    """With a journal: compact it into a snapshot of the shift every this many adopted
    segments (0: never; the journal then grows with the shift)."""


    @model_validator(mode="before")
    @classmethod
    def _window_or_horizon(cls, data: Any) -> Any:
        if isinstance(data, dict) and "window" in data and "horizon" in data:
            raise ValueError("give lifelong.window or horizon (its other name), not both")
        return data

    @model_validator(mode="after")
    def _one_map(self) -> LifelongSettings:
        if self.problem is not None and self.map is not None:
            raise ValueError("give lifelong.problem (its own map) or lifelong.map, not both")
        return self


class ConfigError(ValueError):
    """The configuration (file, environment or arguments) is invalid; the message says why."""


class GatewayConfig(BaseSettings):
    """Everything ``fleetgate serve`` can be told."""

    model_config = SettingsConfigDict(env_prefix="FLEETGATE_", env_nested_delimiter="__",
                                      extra="forbid", allow_inf_nan=False)

    host: str = "127.0.0.1"
    port: int = Field(default=8080, ge=0, le=65535)
    tokens: TokensConfig = TokensConfig()
    allow_demo_tokens: bool = False
    tls: TlsConfig | None = None
    vda5050: Vda5050Config | None = None
    """VDA 5050 vehicles driven over MQTT beside the websocket robots (docs/vda5050.md)."""
    allow_plaintext: bool = False
    """Serve plain ws:// and http:// on a non-loopback host (only behind a proxy that
    terminates TLS; without it such a host needs ``[tls]``)."""
    allowed_origins: list[str] = Field(default_factory=list)
    """Browser origins (``https://host:port``) allowed besides the gateway's own."""
    login_ttl_s: float = Field(default=12 * 3600.0, gt=0)
    """Lifetime of a GUI login (the session cookie)."""

    map: str | None = "lab"
    scen: str | None = None
    agents: int | None = Field(default=None, ge=1)
    instance: Path | None = None
    generate_seed: int = 0
    autostart: bool = False

    motion: Literal["omni", "turning"] = "turning"
    """Motion model of the plans the gateway makes (a loaded plan brings its own): real
    robots turn in place, so ``turning`` by default."""
    start_heading: int = Field(default=0, ge=0, le=3)
    """Turning: the start heading of robots whose instance gives none (0 east, 1 south, 2 west,
    3 north)."""

    policy: PolicyName = "slack"
    policy_seed: int = 0
    threshold_ms: float = Field(default=PAPER.threshold_ms, ge=0)
    max_replans: int = Field(default=PAPER.max_replans, ge=0)
    block_history_ms: list[Annotated[float, Field(gt=0)]] = Field(default_factory=list)
    """How long blocks the fleet saw before lasted (ms): where the block estimates of the
    informed and shadow policies start; each run adds the blocks it saw for the next."""
    action_ms: float = Field(default=PAPER.action_ms, gt=0)
    """t_x of every action of a robot that has no model in ``robot_model``."""
    robot_models: dict[str, RobotModel] = Field(default_factory=dict)
    """Named robot models: the monitor's t_x per action kind (move, turn, wait)."""
    robot_model: dict[int, str] = Field(default_factory=dict)
    """Robot id -> the name of its model in ``robot_models``."""
    drop_waits: bool = False
    dispatch_lookahead: int = Field(default=1, ge=0)
    """Actions queued on a robot beyond its current one (0: dispatch only when all ADG edges
    are done; 1: release the next action early so the robot need not wait for a round trip)."""
    solver_time_limit_s: float = Field(default=10.0, gt=0)
    fallback_s: float | None = Field(default=None, gt=0)
    """If CBS finds no plan within ``solver_time_limit_s``, seconds more for the prioritised
    planner (a feasible, not optimal plan; logged as a warning). None: no fallback."""
    speed: float = Field(default=1.0, gt=0, le=100)

    state_period_ms: float = Field(default=5000.0, gt=0)
    ping_interval_s: float = Field(default=5.0, gt=0)
    ping_timeout_s: float = Field(default=5.0, gt=0)
    close_timeout_s: float = Field(default=2.0, gt=0)
    handshake_timeout_s: float = Field(default=10.0, gt=0)
    """TLS plus an HTTP request's head (and, for the task API, its body; for a websocket, the
    upgrade) must be done within this."""
    keep_alive_s: float = Field(default=5.0, gt=0)
    """An idle HTTP keep-alive connection is closed after this."""
    hello_timeout_s: float = Field(default=10.0, gt=0)
    """A robot's websocket must say hello within this (else closed 4001)."""
    idle_timeout_s: float = Field(default=60.0, gt=0)
    """A robot's websocket that sends nothing for this long is closed (4002)."""
    max_connections: int = Field(default=10000, ge=1)
    """Open websocket connections at most (more get HTTP 503); also capped by the fd limit.
    With ``workers``, the cap of each worker process and of the gateway's own."""
    workers: int = Field(default=0, ge=0, le=64)
    """Worker processes that serve the robots' websockets (TLS, handshake, message checks) on
    the gateway's port and pass them to its own process, the only writer of the executor and
    the journal (docs/workers.md); 0: the gateway's own process serves everything."""
    batch_ms: float = Field(default=5.0, ge=0, le=100)
    """Under a steady stream of events, how long one may wait to share its batch with the
    next: the gateway's process handles them, commits the journal once and writes once to
    each worker per batch, at most one batch per ``batch_ms``; with ``workers``, a worker
    sends what it received to the gateway's process once per ``batch_ms`` too. An event after
    a quiet spell is handled at once. Less CPU per action at high rates, up to this much more
    latency (twice with workers); 0: one batch per turn of the event loop. Not in virtual
    time (a simulation's events are batched by their instant)."""
    worker_timeout_s: float = Field(default=10.0, gt=0)
    """A worker that has not answered the gateway's ping (one a second) for this long hangs:
    it is killed and started again (its robots reconnect, as after a cut link)."""
    worker_buffer_bytes: int = Field(default=32 * 1024 * 1024, ge=0)
    """Bytes the gateway's process may hold for a worker that does not read them: one more
    and the worker is killed and started again (so a hung worker cannot grow the gateway's
    memory without bound)."""
    max_http_connections: int = Field(default=1000, ge=1)
    """Open HTTP connections at most (websockets not counted): each is unauthenticated until
    its request's head is read; a request on a connection over this gets 503."""
    send_queue: int = Field(default=4096, ge=1)
    max_errors: int = Field(default=20, ge=1)
    error_decay_s: float = Field(default=1.0, gt=0)
    """The error budget forgets one error per this many seconds."""
    rate_per_s: float = Field(default=500.0, gt=0)
    rate_burst: float = Field(default=1000.0, ge=1)
    slack_series_len: int = Field(default=3000, ge=10)

    lifelong: LifelongSettings | None = None
    """Lifelong mode (None: execute one plan, the default)."""

    static_dir: Path | None = None
    trace: Path | None = None
    journal: Path | None = None
    """The run journal (SQLite, docs/journal.md): a restarted gateway resumes the journaled run.
    ``fleetgate serve`` defaults to ``journal.sqlite`` in its state directory
    (:func:`default_journal`); None here (the library) journals nothing."""
    log_level: Literal["DEBUG", "INFO", "WARNING", "ERROR"] = "INFO"
    log_format: Literal["text", "json"] = "text"
    log_file: Path | None = None
    """Append logs here instead of writing them on stderr."""

    @property
    def shift_map(self) -> str | None:
        """The map of a lifelong shift: ``lifelong.map``, else a ``map`` given at the top level
        (None: the problem's, or the generated warehouse)."""
        if self.lifelong is None or self.lifelong.map is not None:
            return None if self.lifelong is None else self.lifelong.map
        return self.map if "map" in self.model_fields_set else None

    @property
    def loopback(self) -> bool:
        """True if the gateway listens on a loopback address only."""
        return _is_loopback(self.host)

    @model_validator(mode="after")
    def _models_exist(self) -> GatewayConfig:
        unknown = sorted({m for m in self.robot_model.values() if m not in self.robot_models})
        if unknown:
            raise ValueError(f"robot_model names unknown robot models {unknown}; "
                             f"robot_models defines {sorted(self.robot_models)}")
        return self

    @model_validator(mode="after")
    def _demo_tokens_only_on_loopback(self) -> GatewayConfig:
        t = self.tokens
        demo = (bool(t.demo_robot_prefix) or "demo-operator" in t.operators
                or "demo-world" in t.world)
        if demo and not self.allow_demo_tokens and not _is_loopback(self.host):
            raise ValueError(f"demo tokens on non-loopback host {self.host!r}: configure "
                             'tokens (and demo_robot_prefix = "") or set allow_demo_tokens')
        return self

    @model_validator(mode="after")
    def _safe_on_a_public_host(self) -> GatewayConfig:
        if _is_loopback(self.host):
            return self
        t = self.tokens
        fixes = []
        if any(PLACEHOLDER in token for token in (*t.operators, *t.world, *t.robots)):
            fixes.append(f"replace every {PLACEHOLDER} token with a random one (python -c "
                         '"import secrets; print(secrets.token_urlsafe(32))")')
        if self.tls is None and not self.allow_plaintext:
            fixes.append("add [tls] (deploy/gateway.tls.example.toml, deploy/TLS.md) or set "
                         "allow_plaintext = true behind a TLS proxy")
        if fixes:
            raise ValueError(f"refusing to serve on non-loopback host {self.host!r}: "
                             f"{'; '.join(fixes)} (or listen on host = \"127.0.0.1\")")
        return self

    @model_validator(mode="after")
    def _map_needs_agents(self) -> GatewayConfig:
        s = self.lifelong
        if s is not None:  # a map given at the top level is the shift's (shift_map)
            if "map" in self.model_fields_set and self.map is not None and (
                    s.map is not None or s.problem is not None):
                other = "map" if s.map is not None else "problem"
                raise ValueError(f"map = {self.map!r} and lifelong.{other} both give the "
                                 "shift's map: keep one")
            return self
        if "map" in self.model_fields_set and self.map is not None and self.instance is None \
                and self.scen is None and self.agents is None:
            raise ValueError(f"map = {self.map!r} needs scen or agents to load an instance at "
                             "start (leave map out to start empty and load from the GUI)")
        return self


def default_journal() -> Path:
    """``journal.sqlite`` in the state directory: systemd's ``$STATE_DIRECTORY``, else
    ``$XDG_STATE_HOME/fleetgate``, else ``~/.local/state/fleetgate``."""
    state = os.environ.get("STATE_DIRECTORY", "").split(":")[0]
    if state:
        return Path(state) / "journal.sqlite"
    xdg = os.environ.get("XDG_STATE_HOME")
    base = Path(xdg) if xdg else Path.home() / ".local" / "state"
    return base / "fleetgate" / "journal.sqlite"


def _is_loopback(host: str) -> bool:
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def _first_error(exc: ValidationError) -> str:
    err = exc.errors(include_url=False)[0]
    where = ".".join(str(p) for p in err["loc"])
    msg = str(err["msg"]).removeprefix("Value error, ")
    return f"{where}: {msg}" if where else msg


def load_config(path: str | Path | None = None, **overrides: Any) -> GatewayConfig:
    """The configuration from ``path`` (``.json`` or ``.toml``), the environment and
    ``overrides`` (highest priority; None values are ignored). Raises ConfigError."""
    given = {k: v for k, v in overrides.items() if v is not None}
    file = Path(path) if path is not None else None
    if file is not None:
        if file.suffix not in (".json", ".toml"):
            raise ConfigError(f"config file must end in .json or .toml: {file}")
        if not file.is_file():
            raise ConfigError(f"config file not found: {file}")

    class _FromFile(GatewayConfig):
        @classmethod
        def settings_customise_sources(
            cls,
            settings_cls: type[BaseSettings],
            init_settings: PydanticBaseSettingsSource,
            env_settings: PydanticBaseSettingsSource,
            dotenv_settings: PydanticBaseSettingsSource,
            file_secret_settings: PydanticBaseSettingsSource,
        ) -> tuple[PydanticBaseSettingsSource, ...]:
            if file is None:
                return (init_settings, env_settings)
            source: PydanticBaseSettingsSource = (
                TomlConfigSettingsSource(settings_cls, file) if file.suffix == ".toml"
                else JsonConfigSettingsSource(settings_cls, file))
            return (init_settings, env_settings, source)

    try:
        merged = _FromFile(**given)
    except ValidationError as exc:
        raise ConfigError(f"bad configuration: {_first_error(exc)}") from None
    except ValueError as exc:  # unreadable TOML/JSON
        raise ConfigError(f"cannot read {file}: {exc}") from None
    return GatewayConfig.model_validate(merged.model_dump(exclude_unset=True))
