"""``fleetgate sim``: simulated robots (and the simulated world) for a running gateway.

Each robot connects to ``--connect`` with its own token (and, for ``wss://`` with mutual TLS,
its own client certificate: ``--cert``/``--key`` templates with ``{id}``), executes what it is
dispatched on a shared simulated floor, and reconnects when its link drops. The world
connection receives the operator's ``place_intruder`` and the gateway's ``set_speed``. Runs until
Ctrl-C. With ``--vda5050`` the robots are simulated VDA 5050 vehicles on an MQTT broker instead
(the gateway drives them through its ``[vda5050]`` section).
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING

from gateway.runtime.exits import EXIT_BAD_INPUT, UsageError

if TYPE_CHECKING:
    import ssl

    from gateway.vda5050.config import Vda5050Config
    from sim_clients.fleet import SimFleet


def parse_robots(spec: str) -> list[int]:
    """``"10"`` = robots 0..9; ``"3-5,8"`` = robots 3, 4, 5 and 8. ValueError if malformed or
    if it names no robot (``"0"``)."""
    spec = spec.strip()
    if spec.isdigit():
        if int(spec) == 0:
            raise ValueError("--robots 0 names no robot: give a count >= 1 or ids like 0-9,12 "
                             "(robot 0 alone: 0-0)")
        return list(range(int(spec)))
    robots: list[int] = []
    for part in spec.split(","):
        lo, dash, hi = part.strip().partition("-")
        if not lo.isdigit() or (dash and not hi.isdigit()):
            raise ValueError(f"robots must be a count or ids like 0-9,12; got {spec!r}")
        first, last = int(lo), int(hi) if dash else int(lo)
        if last < first:
            raise ValueError(f"empty robot range {part!r}")
        robots.extend(range(first, last + 1))
    if len(set(robots)) != len(robots):
        raise ValueError(f"a robot is listed twice in {spec!r}")
    return robots


def token_source(spec: str) -> Callable[[int], str]:
    """Robot id -> token from a template containing ``{id}``, a JSON file ``{"id": token}``,
    or else one literal token for every robot (a name ending in ``.json`` must be a file)."""
    if "{id}" in spec:
        return lambda r: spec.replace("{id}", str(r))
    if not Path(spec).exists() and not spec.endswith(".json"):
        return lambda r: spec
    try:
        data = json.loads(Path(spec).read_text())
    except OSError as exc:
        raise ValueError(f"--tokens is neither a template with {{id}} nor a readable file: "
                         f"{spec} ({exc.strerror})") from None
    except json.JSONDecodeError as exc:
        raise ValueError(f"--tokens file {spec} is not JSON: {exc.msg}") from None
    if not isinstance(data, dict) or not all(isinstance(v, str) for v in data.values()):
        raise ValueError(f'--tokens file {spec} must map robot ids to tokens: {{"0": "..."}}')
    tokens = {int(k): v for k, v in data.items() if str(k).isdigit()}

    def lookup(r: int) -> str:
        if r not in tokens:
            raise ValueError(f"no token for robot {r} in {spec}")
        return tokens[r]

    return lookup


def tls_contexts(args: argparse.Namespace, robots: list[int], tokens: Callable[[int], str]
                 ) -> Callable[[str], ssl.SSLContext | None] | None:
    """token -> SSL context of its connection for a ``wss://`` gateway (robot ``r`` presents
    the certificate ``--cert`` with ``{id}`` = r; the world none); None for ``ws://``.
    ValueError if a file cannot be loaded or TLS options come with ``ws://``."""
    if not args.connect.startswith("wss://"):
        if args.ca or args.cert or args.key:
            raise ValueError("--ca, --cert and --key need a wss:// gateway URL")
        return None
    if args.key and not args.cert:
        raise ValueError("--key needs --cert")
    from protocol.tls import client_context

    def load(r: int | None) -> ssl.SSLContext:
        cert = args.cert.replace("{id}", str(r)) if args.cert and r is not None else None
        key = args.key.replace("{id}", str(r)) if args.key and r is not None else None
        try:
            return client_context(args.ca, cert, key)
        except OSError as exc:  # ssl.SSLError too
            raise ValueError(f"cannot load the TLS files for robot {r} "
                             f"({args.ca}, {cert}, {key}): {exc}") from None

    contexts = {tokens(r): load(r) for r in robots}
    shared = load(None)
    return lambda token: contexts.get(token, shared)


def robots_connected(n: int) -> str:
    """``"1 robot connected"``, ``"10 robots connected"``."""
    return f"{n} robot{'' if n == 1 else 's'} connected"


async def _connect(fleet: SimFleet, url: str) -> None:
    """Start the fleet and say when every robot is connected, or, once, that nothing answers
    at ``url`` yet (the robots keep retrying). RuntimeError if a robot can never connect."""
    import asyncio

    connected = asyncio.ensure_future(_start_and_wait(fleet))
    absent = asyncio.ensure_future(fleet.gateway_absent.wait())
    try:
        await asyncio.wait({connected, absent}, return_when=asyncio.FIRST_COMPLETED)
        if not connected.done():
            print(f"fleetgate sim: no gateway answers at {url} ({fleet.connect_error}); "
                  f"retrying every {fleet.reconnect_delay_s:g} s (Ctrl-C stops)",
                  file=sys.stderr, flush=True)
        await connected
    finally:
        absent.cancel()
    print(f"fleetgate sim: {robots_connected(len(fleet.robots))}", file=sys.stderr, flush=True)


async def _start_and_wait(fleet: SimFleet) -> None:
    await fleet.start()
    await fleet.wait_connected()


async def _run_fleet(fleet: SimFleet, url: str) -> int:
    """Run until Ctrl-C (130) or SIGTERM (0), stopping at once even while connecting."""
    import asyncio

    from fleetgate.userio.signals import StopSignals

    stop = StopSignals()
    body = asyncio.ensure_future(_connect(fleet, url))
    stopped = asyncio.ensure_future(stop.wait())
    try:
        await asyncio.wait({body, stopped}, return_when=asyncio.FIRST_COMPLETED)
        if body.done():
            body.result()  # a robot that can never connect raises here
        await stopped
    finally:
        for task in (body, stopped):
            task.cancel()
        await asyncio.gather(body, stopped, return_exceptions=True)
        await fleet.stop()
    st = fleet.stats
    print(f"fleetgate sim: {len(st.finish_sent)} actions finished, {st.duplicates} duplicates "
          f"dropped, {st.reconnects} reconnects", file=sys.stderr, flush=True)
    return stop.exit_code


def vda_settings(args: argparse.Namespace, robots: list[int]) -> Vda5050Config:
    """The vehicles of ``fleetgate sim --vda5050``: the ``[vda5050]`` section of ``--config``
    (a gateway configuration file), or vehicles ``fleetgate``/``sim<id>`` for ``--robots``;
    ``--broker`` overrides the broker's URL. ValueError (one line) if that fails."""
    from pydantic import ValidationError

    from gateway.server.config import ConfigError, load_config
    from gateway.vda5050.broker import BrokerConfig
    from gateway.vda5050.config import Vda5050Config, VehicleConfig

    if args.config is not None:
        try:
            found = load_config(args.config).vda5050
        except ConfigError as exc:
            raise ValueError(str(exc)) from None
        if found is None:
            raise ValueError(f"{args.config} has no [vda5050] section")
        config = found
    else:
        config = Vda5050Config(version=args.vda_version, vehicles=[
            VehicleConfig(manufacturer="fleetgate", serial_number=f"sim{r}", robot_id=r)
            for r in robots])
    if args.broker is not None:
        try:
            broker = BrokerConfig.model_validate(
                {**config.broker.model_dump(), "url": args.broker})
        except ValidationError as exc:
            raise ValueError(f"--broker: {exc.errors()[0]['msg']}") from None
        config = config.model_copy(update={"broker": broker})
    return config


async def _run_vehicles(config: Vda5050Config, speed: float) -> int:
    """Run the vehicles until Ctrl-C (130) or SIGTERM (0)."""
    import asyncio

    from fleetgate.userio.signals import StopSignals
    from sim_clients.vda_fleet import make_vehicles, run_fleet
    from sim_clients.world import World

    stop = StopSignals()
    vehicles = make_vehicles(config, World(), speed=speed)
    print(f"fleetgate sim: {len(vehicles)} VDA 5050 vehicles on {config.broker.url} "
          f"(topics {config.interface_name}/v2/<manufacturer>/<serial>/...)", file=sys.stderr,
          flush=True)
    done = asyncio.Event()
    running = asyncio.ensure_future(run_fleet(vehicles, config.broker, done))
    stopped = asyncio.ensure_future(stop.wait())
    try:
        await asyncio.wait({running, stopped}, return_when=asyncio.FIRST_COMPLETED)
        done.set()
        await running  # a broker that cannot be reached raises here
    finally:
        stopped.cancel()
    print(f"fleetgate sim: {sum(v.edges_driven for v in vehicles)} edges driven",
          file=sys.stderr, flush=True)
    return stop.exit_code


def _run_vda(args: argparse.Namespace) -> int:
    import asyncio

    import aiomqtt

    try:
        config = vda_settings(args, parse_robots(args.robots))
    except ValueError as exc:
        raise UsageError(str(exc)) from None
    if not 0 < args.speed <= 100:
        raise UsageError(f"--speed must be in (0, 100], got {args.speed:g}")
    failed: list[BaseException] = []
    code = EXIT_BAD_INPUT
    try:
        code = asyncio.run(_run_vehicles(config, args.speed))
    except* aiomqtt.MqttError as group:
        failed.extend(group.exceptions)
    if failed:
        print(f"fleetgate sim: cannot reach the MQTT broker at {config.broker.url}: "
              f"{failed[0]}", file=sys.stderr)
        return EXIT_BAD_INPUT
    return code


def _run(args: argparse.Namespace) -> int:
    import asyncio

    from sim_clients.connect import websocket_connector
    from sim_clients.fleet import SimFleet

    if args.vda5050:
        return _run_vda(args)
    try:
        robots = parse_robots(args.robots)
        tokens = token_source(args.tokens)
        for r in robots:
            tokens(r)
    except ValueError as exc:
        raise UsageError(str(exc)) from None
    if not args.connect.startswith(("ws://", "wss://")):
        raise UsageError(f"--connect must be a ws:// or wss:// URL, got {args.connect!r}")
    try:
        tls = tls_contexts(args, robots, tokens)
    except ValueError as exc:
        raise UsageError(str(exc)) from None
    if args.reconnect_s <= 0:
        raise UsageError(f"--reconnect-s must be positive, got {args.reconnect_s}")

    async def main() -> int:
        world = None if args.world_token == "none" else args.world_token
        fleet = SimFleet(websocket_connector(args.connect, tls), robots, token=tokens,
                         world_token=world, reconnect_delay_s=args.reconnect_s,
                         protocol=args.protocol)
        return await _run_fleet(fleet, args.connect)

    try:
        return asyncio.run(main())
    except RuntimeError as exc:  # a robot's handshake was refused, TLS verification failed
        print(f"fleetgate sim: {exc}", file=sys.stderr)
        return EXIT_BAD_INPUT


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    """Add ``fleetgate sim``."""
    p = sub.add_parser(
        "sim", help="simulated robots for a running gateway",
        description="Connect simulated robots (and the simulated world, which places the "
                    "operator's intruders) to a running gateway; they execute what they are "
                    "dispatched on a shared simulated floor and reconnect when their link "
                    "drops. Stops on Ctrl-C. The world's speed follows the gateway's.")
    p.add_argument("--connect", metavar="URL", default="ws://127.0.0.1:8080/ws",
                   help="the gateway's websocket URL (default ws://127.0.0.1:8080/ws)")
    p.add_argument("--robots", metavar="SPEC", default="10",
                   help="how many robots (0..N-1) or which: e.g. 10, 0-4, 0,2,7 (default 10)")
    p.add_argument("--tokens", metavar="TEMPLATE|FILE", default="demo-robot-{id}",
                   help="robot tokens: a template with {id} (default demo-robot-{id}), a "
                        'JSON file {"0": "token", ...}, or one literal token for every robot')
    p.add_argument("--world-token", default="demo-world",
                   help="token of the world connection, or 'none' (default demo-world)")
    p.add_argument("--ca", metavar="FILE",
                   help="wss://: PEM CA of the gateway's certificate (default: system CAs)")
    p.add_argument("--cert", metavar="TEMPLATE",
                   help="wss:// with mutual TLS: each robot's PEM client certificate, {id} = "
                        "its robot id (e.g. certs/robot-{id}.pem)")
    p.add_argument("--key", metavar="TEMPLATE",
                   help="the certificates' PEM keys if not in them (e.g. certs/robot-{id}.key)")
    p.add_argument("--protocol", type=int, choices=[2, 3], default=3,  # PROTOCOL_VERSION
                   # (protocol.messages is not imported: building the parser stays light)
                   help="the protocol version the robots speak (default %(default)s: no ack; "
                        "2: an ack per action)")
    p.add_argument("--reconnect-s", type=float, default=1.0,
                   help="seconds between reconnection attempts (default 1)")
    vda = p.add_argument_group("VDA 5050 vehicles (docs/vda5050.md)")
    vda.add_argument("--vda5050", action="store_true",
                     help="simulate VDA 5050 vehicles on an MQTT broker instead of websocket "
                          "robots (each stands on the first node of its first order)")
    vda.add_argument("--broker", metavar="URL",
                     help="the broker, mqtt://HOST:PORT (default: the config's, else "
                          "mqtt://127.0.0.1:1883)")
    vda.add_argument("--config", metavar="FILE", type=Path,
                     help="a gateway configuration: its [vda5050] section names the vehicles "
                          "(default: fleetgate/sim<id> for --robots)")
    vda.add_argument("--vda-version", choices=["2.0.0", "2.1.0"], default="2.1.0",
                     help="protocol version of the vehicles without --config (default 2.1.0)")
    vda.add_argument("--speed", metavar="F", type=float, default=1.0,
                     help="vehicles run F times faster than 1 s per move (default 1)")
    p.set_defaults(func=_run)
