"""Fuzz benchmark: hostile frames against a live gateway while a well-behaved fleet runs.

A gateway listens on 127.0.0.1 (real websockets); a simulated fleet executes a plan through
it (``sim_clients.fleet``, policy none, no intruder) in virtual time (driver 2: a looptime
loop, the fleet on in-memory links), so that its SOC is exact and does not depend on how busy
the machine is: the fuzz traffic over the real sockets of the same loop may cost CPU but no
virtual time, and the SOC of every fuzzed run must EQUAL the undisturbed run's. Meanwhile
``--concurrency`` fuzz connections (robot tokens of ids outside the plan, the world and an
operator; some with bad tokens or a foreign Origin) send ``--frames`` frames:

* messages drawn by hypothesis from the protocol models (every message type, each field
  from its annotation: constraints, patterns, nested models), then
* mutated: a field dropped, replaced by an arbitrary JSON value or a wrong type, an extra
  field, another ``type``; or byte-level: bytes flipped, inserted, deleted, truncated,
  repeated; or an attack: deep nesting, 5,000-digit integers, strings over the size limit
  in bytes, invalid UTF-8, binary frames, frames over the hard limit.

Frames that would be legitimate commands of the operator or reports of the world are not sent
(they would change the run on purpose); everything a robot of another id may send is.

Counted: handler exceptions (records of level ERROR from the gateway, websockets or asyncio
loggers and loop exceptions; the gateway's ``fleetgate_handler_failures``: must be 0), replies
by error code, close codes, and the fleet's runs (at most ``per_run`` frames each): SOC against
the undisturbed run measured in the same invocation (``soc_ratio`` must be 1) and the trace
checker's verdict of every run (``trace_errors`` must be 0). Throughput is frames per CPU
second of this process (gateway, fleet and fuzzer together).

Prints ONE JSON line. ``--frames 100000`` is the benchmark; the test suite runs a few thousand
(tests/server/test_fuzz.py)::

    .venv/bin/python bench/fuzz.py --frames 100000 --json
"""

from __future__ import annotations

import fleetgate.userio.script  # noqa: F401 (first: Ctrl-C while importing is one line)

# isort: split

import asyncio
import contextlib
import itertools
import json
import logging
import random
import tempfile
import time
import types
import typing
from collections import Counter
from collections.abc import Iterator
from dataclasses import dataclass, field
from enum import Enum
from pathlib import Path
from typing import Annotated, Any, Literal

from hypothesis import HealthCheck, Phase, given, settings
from hypothesis import seed as hypothesis_seed
from hypothesis import strategies as st
from pydantic import BaseModel
from websockets.asyncio.client import connect
from websockets.exceptions import ConnectionClosed, InvalidHandshake, InvalidStatus

from fleetgate.userio.exits import CommandParser, run_main
from gateway.planning.instance import load_instance
from gateway.planning.solver import solve
from gateway.runtime import mapstore
from gateway.runtime.deadline import WallDeadline
from gateway.server.clock import VirtualClock, run_virtual
from gateway.server.config import GatewayConfig
from gateway.server.gateway import Gateway
from gateway.server.planner import Problem
from gateway.server.wire.transport import HARD_MAX_BYTES
from protocol import (
    MAX_MESSAGE_BYTES,
    OPERATOR_TYPES,
    AnyMessage,
    GetSnapshot,
    ProtocolError,
    decode,
)
from sim_clients.fleet import fleet_for, run_in_process
from tracecheck import check_trace, read_trace

MAP, SCEN, AGENTS = "lab", "lab-random-1", 8
FOREIGN_ROBOTS = range(100, 110)
"""Robot ids the fuzzer connects as: outside the plan, so the fleet's own links stay."""


# ------------------------------------------------------------------------- model strategies
def _strategy(ann: Any) -> st.SearchStrategy[Any]:
    """JSON-ready values for a pydantic field annotation (models become dicts)."""
    origin, args = typing.get_origin(ann), typing.get_args(ann)
    if isinstance(ann, type) and issubclass(ann, BaseModel):
        return model_dicts(ann)
    if isinstance(ann, type) and issubclass(ann, Enum):
        return st.sampled_from([e.value for e in ann])
    if origin is Annotated:
        base, *meta = args
        pattern = next((getattr(m, "pattern", None) for m in meta
                        if getattr(m, "pattern", None)), None)
        if pattern is not None:
            return st.from_regex(pattern, fullmatch=True)
        if typing.get_origin(base) in (list, tuple, typing.Union, types.UnionType):
            return _strategy(base)
        return st.from_type(ann)
    if origin in (typing.Union, types.UnionType):
        return st.one_of([_strategy(a) for a in args])
    if origin is list:
        return st.lists(_strategy(args[0]), max_size=4)
    if origin is tuple:
        return st.tuples(*map(_strategy, args)).map(list)
    if origin is dict:
        return st.dictionaries(st.text(max_size=8), _strategy(args[1]), max_size=3)
    if origin is Literal:
        return st.sampled_from(args)
    return st.from_type(ann)


def model_dicts(model: type[BaseModel]) -> st.SearchStrategy[dict[str, Any]]:
    """Dicts with every field of ``model`` drawn from its annotation (and metadata)."""
    fields = {}
    for name, info in model.model_fields.items():
        ann: Any = info.annotation
        if info.metadata:
            ann = Annotated[(ann, *info.metadata)]
        fields[name] = _strategy(ann)
    return st.fixed_dictionaries(fields)


def message_strategy() -> st.SearchStrategy[dict[str, Any]]:
    """Any protocol message as a dict (type and version right, fields drawn from the model)."""
    members = typing.get_args(AnyMessage)
    return st.one_of([model_dicts(m) for m in members])


def draw_messages(n: int, seed: int) -> list[dict[str, Any]]:
    """``n`` messages drawn by hypothesis (generate phase only, reproducible by ``seed``)."""
    out: list[dict[str, Any]] = []

    @hypothesis_seed(seed)
    @settings(max_examples=n, database=None, phases=[Phase.generate], deadline=None,
              suppress_health_check=list(HealthCheck))
    @given(message_strategy())
    def collect(message: dict[str, Any]) -> None:
        out.append(message)

    collect()
    return out


# ------------------------------------------------------------------------- mutations
def _json_value(rng: random.Random) -> Any:
    return rng.choice([None, True, False, 0, -1, 2**63, 1.5, float("1e308"), "", "x" * 70,
                       "0.0.0", "3", "é²", [], [1, 2], [[0, 0]], {}, {"a": 1}])


def _mutate_dict(rng: random.Random, msg: dict[str, Any]) -> dict[str, Any]:
    msg = dict(msg)
    keys = list(msg)
    op = rng.randrange(6)
    if op == 0 and keys:
        del msg[rng.choice(keys)]
    elif op == 1 and keys:
        msg[rng.choice(keys)] = _json_value(rng)
    elif op == 2:
        msg[rng.choice(["extra", "robot_id", "token", "__proto__"])] = _json_value(rng)
    elif op == 3:
        msg["type"] = rng.choice(["hello", "start", "intruder", "finished", "teleport", 7, None])
    elif op == 4:
        msg["v"] = rng.choice([0, 2, True, 1.0, "1", None])
    elif op == 5 and "seq" in msg:
        msg["seq"] = rng.choice([True, "1", -1, 1.0, 10**40])
    return msg


def _mutate_bytes(rng: random.Random, data: bytes) -> bytes:
    buf = bytearray(data)
    for _ in range(rng.randint(1, 4)):
        op = rng.randrange(5)
        pos = rng.randrange(len(buf) + 1)
        if op == 0 and buf:
            buf[min(pos, len(buf) - 1)] = rng.randrange(256)
        elif op == 1:
            buf[pos:pos] = bytes([rng.choice(b'{}[]",:\\0e-\xff\xc3')])
        elif op == 2:
            del buf[pos:pos + rng.randint(1, 8)]
        elif op == 3:
            del buf[pos:]
        else:
            buf[pos:pos] = buf[pos:pos + rng.randint(1, 32)] * rng.randint(1, 50)
    return bytes(buf)


def _attack(rng: random.Random) -> str | bytes:
    kind = rng.randrange(7)
    if kind == 0:
        return "[" * rng.choice([9, 100, 20_000]) + "]" * rng.choice([0, 9])
    if kind == 1:
        return '{"v": 1, "type": "state", "msg_id": "a", "seq": 0, "robot_id": ' + \
            "9" * rng.choice([33, 4301, 5000]) + "}"
    if kind == 2:
        return json.dumps({"v": 1, "type": "state", "msg_id": "a", "seq": 0, "robot_id": 100,
                           "pad": "é" * (MAX_MESSAGE_BYTES // 2 + 1)}, ensure_ascii=False)
    if kind == 3:
        return b'{"v": 1, "type": "hello", "msg_id": "a", "seq": 0, "robot_id": 100}'
    if kind == 4:
        return "x" * (HARD_MAX_BYTES + 1)
    if kind == 5:
        return '{"v": 1, "type": "hello", "msg_id": "' + "\\ud800" * 10 + '", "seq": 0}'
    return json.dumps({"v": 1, "type": "hello", "msg_id": "a", "seq": 0, "robot_id": "100"})


def frames(n: int, seed: int) -> Iterator[str | bytes]:
    """``n`` hostile frames (see the module doc): a fifth are hypothesis messages as drawn
    (at most 5,000 draws, done before this returns), the rest mutations of them, byte-level
    mutations and attacks."""
    return _frames(n, random.Random(seed), draw_messages(min(5000, max(50, n // 5)), seed))


def _frames(n: int, rng: random.Random, drawn: list[dict[str, Any]]
            ) -> Iterator[str | bytes]:
    for i in range(n):
        msg = drawn[i % len(drawn)]
        op = rng.randrange(10)
        if op < 2:
            yield json.dumps(msg)
        elif op < 5:
            yield json.dumps(_mutate_dict(rng, msg))
        elif op < 8:
            raw = _mutate_bytes(rng, json.dumps(msg).encode())
            yield raw.decode("utf-8", "replace") if rng.random() < 0.9 else raw
        else:
            yield _attack(rng)


# ------------------------------------------------------------------------- the run
@dataclass
class FuzzStats:
    """What the fuzz connections saw."""

    sent: int = 0
    skipped: int = 0
    connections: int = 0
    refused: Counter[int] = field(default_factory=Counter)
    replies: Counter[str] = field(default_factory=Counter)
    closes: Counter[int] = field(default_factory=Counter)


class ErrorRecords(logging.Handler):
    """Counts records of level ERROR and above (the gateway's handler failures, websockets'
    and asyncio's unhandled exceptions)."""

    def __init__(self) -> None:
        super().__init__(logging.ERROR)
        self.records: list[str] = []

    def emit(self, record: logging.LogRecord) -> None:
        self.records.append(f"{record.name}: {record.getMessage()}")


def _harmless(role: str, frame: str | bytes) -> bool:
    """False for a frame that would be a legitimate operator command (except get_snapshot)
    or world report: those change the run on purpose."""
    if role == "robot" or isinstance(frame, bytes):
        return True
    try:
        message = decode(frame)
    except ProtocolError:
        return True
    if role == "operator":
        return message.type not in OPERATOR_TYPES or isinstance(message, GetSnapshot)
    return False


_ROLES = [("robot", "demo-robot-{r}", None), ("world", "demo-world", None),
          ("operator", "demo-operator", None), ("robot", "nope-{r}", None),
          ("operator", "demo-operator", "http://evil.example")]


async def _fuzz_connection(url: str, source: Iterator[str | bytes], stats: FuzzStats,
                           rng: random.Random, pace_s: float) -> bool:
    """One connection: send frames until the gateway closes it or frames run out; False when
    the frames ran out."""
    role, token, origin = rng.choice(_ROLES)
    token = token.format(r=rng.choice(FOREIGN_ROBOTS))
    try:
        ws = await connect(url, additional_headers={"Authorization": f"Bearer {token}"},
                           origin=origin, proxy=None, compression=None,  # type: ignore[arg-type]
                           max_size=None, open_timeout=10)
    except InvalidStatus as exc:
        stats.refused[exc.response.status_code] += 1
        return True
    except (OSError, InvalidHandshake, TimeoutError):
        stats.refused[0] += 1
        return True
    stats.connections += 1

    async def read() -> None:
        with contextlib.suppress(ConnectionClosed):
            async for text in ws:
                try:
                    reply = json.loads(text)
                except ValueError:
                    stats.replies["not-json"] += 1
                    continue
                if reply.get("type") == "error":
                    stats.replies[str(reply.get("code"))] += 1
                elif reply.get("type") in ("ok", "welcome"):
                    stats.replies[reply["type"]] += 1

    reader = asyncio.create_task(read())
    more = True
    try:
        for _ in range(rng.randint(5, 60)):
            frame = next(source, None)
            if frame is None:
                more = False
                break
            if not _harmless(role, frame):
                stats.skipped += 1
                continue
            await ws.send(frame)
            stats.sent += 1
            await asyncio.sleep(pace_s)
    except ConnectionClosed:
        pass
    with contextlib.suppress(ConnectionClosed, TimeoutError):
        async with asyncio.timeout(2):
            await ws.close()
    with contextlib.suppress(TimeoutError, asyncio.CancelledError):
        async with asyncio.timeout(2):
            await reader
    reader.cancel()
    if ws.close_code is not None:
        stats.closes[ws.close_code] += 1
    return more


async def fuzz(url: str, source: Iterator[str | bytes], stats: FuzzStats, concurrency: int,
               seed: int, pace_s: float = 0.0) -> None:
    """Run ``concurrency`` fuzz connections in turn until ``source`` is exhausted."""
    rng = random.Random(seed)

    async def worker() -> None:
        while await _fuzz_connection(url, source, stats, rng, pace_s):
            pass

    await asyncio.gather(*(worker() for _ in range(concurrency)))


@dataclass
class RunOutcome:
    """One execution of the plan (times in virtual plan ms)."""

    soc_ms: float
    makespan_ms: float
    trace_errors: int
    collisions: int


def _problem() -> Problem:
    inst = load_instance(mapstore.resolve(MAP, "map"), mapstore.resolve(SCEN, "scen"), AGENTS)
    plan = solve(inst.grid, inst.starts, inst.goals, deadline=WallDeadline(30)).plan
    return Problem(inst, f"{MAP}/{SCEN}", plan)


async def run_once(problem: Problem, trace: Path, hostile: Iterator[str | bytes] | None,
                   stats: FuzzStats, concurrency: int, seed: int, pace_s: float
                   ) -> RunOutcome:
    """One run of the fleet on a fresh gateway in virtual time, with the fuzzer hitting its
    websockets if ``hostile`` (each fuzz connection waits ``pace_s`` of virtual time between
    frames, so that the frames spread over the run). Returns when the run is complete and the
    fuzzer has sent its frames."""
    config = GatewayConfig(port=0, map=None, policy="none", trace=trace, close_timeout_s=1.0,
                           workers=0)  # virtual time: in this process (workers: test_workers.py)
    async with Gateway(config, clock=VirtualClock()) as gw:
        port = await gw.listen()
        fleet = fleet_for(gw, problem.instance.num_agents, gw.connect, intruder=False)
        fuzzer = (asyncio.ensure_future(fuzz(f"ws://127.0.0.1:{port}/ws", hostile, stats,
                                             concurrency, seed, pace_s))
                  if hostile is not None else None)
        try:
            result = await run_in_process(gw, problem, fleet)
            if fuzzer is not None:
                await fuzzer
        finally:
            if fuzzer is not None:
                fuzzer.cancel()
                await asyncio.gather(fuzzer, return_exceptions=True)
            await fleet.stop()
        failures = int(gw.metrics.handler_failures._value.get())
    report = check_trace(read_trace(trace))
    return RunOutcome(result.soc_ms, result.makespan_ms, len(report.errors) + failures,
                      len(report.collisions) + result.collisions)


class _Budget:
    """Hands out at most ``n`` frames of a generator, one run's share at a time."""

    def __init__(self, source: Iterator[str | bytes], n: int) -> None:
        self._source = source
        self.left = n

    def take(self, n: int) -> Iterator[str | bytes]:
        count = min(n, self.left)
        self.left -= count
        for _ in range(count):
            yield next(self._source)


async def run_fuzz(n_frames: int, *, seed: int = 0, concurrency: int = 8,
                   per_run: int = 5000, problem: Problem | None = None,
                   source: Iterator[str | bytes] | None = None) -> dict[str, Any]:
    """The benchmark (see the module doc); returns the result line as a dict. Must run on a
    virtual-time loop (:func:`gateway.server.clock.run_virtual`). ``problem`` and ``source``
    (:func:`frames`) are made here unless given: made before the loop runs, their CPU-bound
    minutes stay interruptible by Ctrl-C (the loop only sees a signal between callbacks)."""
    problem = problem or _problem()
    errors = ErrorRecords()
    loggers = [logging.getLogger(n) for n in ("fleetgate", "websockets", "asyncio")]
    for lg in loggers:
        lg.addHandler(errors)
    loop = asyncio.get_running_loop()
    loop.set_exception_handler(lambda _loop, ctx: errors.records.append(str(ctx.get("message"))))
    stats = FuzzStats()
    source = source or frames(n_frames, seed)  # drawn before the clock starts
    cpu0, wall0 = time.process_time(), time.perf_counter()
    try:
        with tempfile.TemporaryDirectory() as tmp:
            base = await run_once(problem, Path(tmp) / "base.jsonl", None, stats, concurrency,
                                  seed, 0.0)
            # spread each run's frames over ~80 % of its (virtual) makespan
            pace_s = 0.8 * base.makespan_ms / 1000.0 * concurrency / per_run
            left, runs = n_frames, list[RunOutcome]()
            while left > 0:
                share = min(per_run, left)
                left -= share
                runs.append(await run_once(problem, Path(tmp) / f"{len(runs)}.jsonl",
                                           itertools.islice(source, share), stats,
                                           concurrency, seed + len(runs), pace_s))
    finally:
        for lg in loggers:
            lg.removeHandler(errors)
        loop.set_exception_handler(None)
    cpu = time.process_time() - cpu0
    return {
        "frames": n_frames, "sent": stats.sent, "skipped_legit": stats.skipped,
        "connections": stats.connections, "refused": dict(sorted(stats.refused.items())),
        "handler_exceptions": len(errors.records), "exception_samples": errors.records[:5],
        "replies": dict(sorted(stats.replies.items())),
        "closes": {str(k): v for k, v in sorted(stats.closes.items())},
        "runs": len(runs), "plan_soc": problem.plan.soc if problem.plan else None,
        "soc_ms_undisturbed": base.soc_ms,
        "soc_ms_fuzzed": sorted({r.soc_ms for r in runs}),
        "soc_ratio": (round(max(r.soc_ms for r in runs) / base.soc_ms, 6) if runs else None),
        "trace_errors": base.trace_errors + sum(r.trace_errors for r in runs),
        "collisions": base.collisions + sum(r.collisions for r in runs),
        "frames_per_cpu_s": round(stats.sent / cpu, 1),
        "wall_s": round(time.perf_counter() - wall0, 1),
    }


def main() -> int:
    """Command line: see the module doc."""
    p = CommandParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--frames", type=int, default=100_000)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--concurrency", type=int, default=8, help="fuzz connections at once")
    p.add_argument("--json", action="store_true", help="(the result line is always JSON)")
    args = p.parse_args()
    problem, source = _problem(), frames(args.frames, args.seed)
    result = run_virtual(run_fuzz(args.frames, seed=args.seed, concurrency=args.concurrency,
                                  problem=problem, source=source))
    print(json.dumps(result), flush=True)
    ok = (result["handler_exceptions"] == 0 and result["trace_errors"] == 0
          and result["soc_ms_fuzzed"] in ([], [result["soc_ms_undisturbed"]]))
    return 0 if ok else 1


if __name__ == "__main__":
    run_main("bench/fuzz.py", main)
