"""Worker processes (``workers = N``) over real websockets on 127.0.0.1, in real time (they are
real processes): the robots are served by the workers and complete a journaled run exactly once
(tracecheck), also when a worker is killed with SIGKILL mid-run or hangs (SIGSTOP: it is killed
and restarted, whether found by its unanswered ping or by the owner's unread writes);
everything else (HTTP, operators, refused handshakes) is relayed to the gateway's own process
and answered as on its own port; TLS and mutual TLS end in the workers; bad robot input is
refused there and counted in the owner's metrics."""

from __future__ import annotations

import asyncio
import contextlib
import json
import os
import re
import signal
import socket
import ssl
import subprocess
import sys
import time
import urllib.request
from collections import Counter
from pathlib import Path

import pytest
from websockets.asyncio.client import connect
from websockets.exceptions import ConnectionClosed, InvalidStatus

from bench.fuzz import FuzzStats, frames, fuzz
from gateway.server.clock import VirtualClock
from gateway.server.config import GatewayConfig
from gateway.server.gateway import Gateway
from gateway.server.workers.remote import RemoteSession
from protocol import CloseCode, ErrorCode, Finished, LoadPlan, Start, State
from protocol.robot_session import RobotSession
from sim_clients.connect import websocket_connector
from sim_clients.fleet import SimFleet
from tests.procs import child_pids
from tests.server.conftest import LAB_PATHS, connector, make_config
from tests.server.robots import TestOperator, TestRobot
from tests.server.test_journal import workload
from tests.server.tls_certs import make_certs
from tracecheck import check_trace, read_trace


def _get(url: str, context: ssl.SSLContext | None = None) -> tuple[int, bytes]:
    with urllib.request.urlopen(url, context=context, timeout=10) as answer:
        return answer.status, answer.read()


async def _run_with_a_kill(tmp_path: Path, kill: signal.Signals | None) -> None:
    """A journaled run of 8 robots through 2 workers, the even ones speaking protocol v2 (an
    ``ack`` per action) and the odd ones v3; with ``kill``, that signal hits one of them a
    third of the way through (SIGSTOP: it hangs, and the owner's ping finds it)."""
    trace = tmp_path / "trace.jsonl"
    config = GatewayConfig(port=0, map=None, policy="none", journal=tmp_path / "j.sqlite",
                           trace=trace, speed=20.0, autostart=True, workers=2,
                           worker_timeout_s=2.0)
    problem = workload(8, 30)
    executed: Counter[tuple[int, int, int]] = Counter()

    def on_event(kind: str, plan: int, robot: int, index: int) -> None:
        if kind == "execute":
            executed[(plan, robot, index)] += 1

    async with Gateway(config) as gw:
        port = await gw.listen()
        pool = gw.workers
        assert pool is not None and len(pool.pids) == 2 and os.getpid() not in pool.pids
        fleet = SimFleet(websocket_connector(f"ws://127.0.0.1:{port}/ws"), range(8),
                         clock=gw.clock, send_state=False, reconnect_delay_s=0.05)
        fleet.on_event = on_event
        for r in range(0, 8, 2):
            fleet.add_robot(r).session = RobotSession(r, version=2)
        gw.engine.load(problem)
        await fleet.start()
        try:
            await fleet.wait_connected()
            # every robot is served by a worker: the owner sees it as a RemoteSession, in
            # its robot's protocol version
            assert all(isinstance(gs.link, RemoteSession) for gs in gw.engine.robots.values())
            assert {r: gs.version for r, gs in gw.engine.robots.items()} == {
                r: 2 if r % 2 == 0 else 3 for r in range(8)}
            while gw.engine.status != "running":
                await asyncio.sleep(0.01)
            assert pool.collector_paused  # the workers' collectors too, for the run
            if kill:
                total = sum(len(p) - 1 for p in problem.plan.paths)
                while sum(executed.values()) < total // 3:
                    await asyncio.sleep(0.01)
                victim = pool.pids[0]
                os.kill(victim, kill)
            await asyncio.wait_for(gw.wait_done(), 90)
            if kill:  # its robots went on through the other worker; it is back too
                async with asyncio.timeout(60):
                    while pool.restarts == 0:
                        await asyncio.sleep(0.05)
                assert pool.restarts == 1 and victim not in pool.pids and len(pool.pids) == 2
                assert pool.hangs == (1 if kill == signal.SIGSTOP else 0)
            assert not pool.collector_paused  # the run is complete
        finally:
            await fleet.stop()
            if kill:
                with contextlib.suppress(ProcessLookupError):
                    os.kill(victim, signal.SIGKILL)
    report = check_trace(read_trace(trace))
    assert report.ok, report.errors[:5]
    assert report.actions_run == sum(len(p) - 1 for p in problem.plan.paths)
    assert set(executed.values()) == {1}, "an action executed twice or never"
    assert len(executed) == report.actions_run


def test_robots_served_by_workers_complete_a_journaled_run(tmp_path: Path) -> None:
    asyncio.run(_run_with_a_kill(tmp_path, kill=None))


@pytest.mark.parametrize("kill", [signal.SIGKILL, signal.SIGSTOP], ids=["killed", "stopped"])
def test_a_worker_killed_or_hung_mid_run_is_restarted_and_nothing_is_lost_or_doubled(
        tmp_path: Path, kill: signal.Signals) -> None:
    asyncio.run(_run_with_a_kill(tmp_path, kill))


def test_a_hung_worker_that_leaves_the_owners_writes_unread_is_killed_and_restarted() -> None:
    """A stopped worker (SIGSTOP) reads nothing: once more than ``worker_buffer_bytes`` of the
    owner's commands wait for it (beyond what the socket itself holds), the owner kills it
    rather than grow its buffer; its robot's link is cut, and the robot reconnects through the
    worker started in its place. (Its ping is not what finds it here: the timeout is long.)"""
    async def go() -> None:
        config = make_config(workers=1, worker_buffer_bytes=256 * 1024,
                             worker_timeout_s=600.0)
        async with Gateway(config) as gw:
            await gw.listen()
            pool = gw.workers
            assert pool is not None
            robot = TestRobot(await connector(gw)("demo-robot-0"), 0)
            await robot.hello()
            session = gw.engine.robots[0].link
            assert isinstance(session, RemoteSession)
            victim = pool.pids[0]
            os.kill(victim, signal.SIGSTOP)
            try:
                for _ in range(400):  # up to 400 turns x 64 KiB of error replies for it
                    session.error(ErrorCode.MALFORMED, None, "x" * 65536)
                    await asyncio.sleep(0.001)
                    if pool.hangs:
                        break
                assert pool.hangs == 1
                async with asyncio.timeout(30):
                    while pool.restarts == 0 or gw.engine.robots[0].link is not None:
                        await asyncio.sleep(0.05)
                assert victim not in pool.pids and len(pool.pids) == 1
                with pytest.raises(ConnectionClosed):  # its link was cut
                    while True:
                        await robot.recv()
                again = TestRobot(await connector(gw)("demo-robot-0"), 0)
                assert (await again.hello()).robot_id == 0
                assert isinstance(gw.engine.robots[0].link, RemoteSession)
            finally:
                with contextlib.suppress(ProcessLookupError):
                    os.kill(victim, signal.SIGKILL)

    asyncio.run(asyncio.wait_for(go(), 60))


def test_http_operators_and_refusals_reach_the_owner_through_the_workers() -> None:
    async def go() -> None:
        async with Gateway(make_config(workers=1)) as gw:
            port = await gw.listen()
            status, body = await asyncio.to_thread(_get, f"http://127.0.0.1:{port}/healthz")
            assert status == 200 and json.loads(body)["status"] == "ok"
            code, detail = await gw.command(LoadPlan(msg_id="l", seq=0, map="lab",
                                                     paths=LAB_PATHS[:1]))
            assert code is None, detail
            ws = connector(gw)
            op = TestOperator(await ws("demo-operator"), "op")
            assert (await op.snapshot()).status == "loaded"
            assert gw.engine.feed.operators and not any(
                isinstance(s, RemoteSession) for s in gw.engine.feed.operators)
            with pytest.raises(InvalidStatus) as refused:
                await ws("no-such-token")
            assert refused.value.response.status_code == 403
            robot = TestRobot(await ws("demo-robot-0"), 0)
            await robot.hello()
            assert isinstance(gw.engine.robots[0].link, RemoteSession)
            running = asyncio.create_task(robot.run())
            await op.send(Start)  # the operator's command, relayed, starts the robot's run
            await gw.wait_done()
            running.cancel()
            assert len(robot.finished) == len(LAB_PATHS[0]) - 1

    asyncio.run(asyncio.wait_for(go(), 60))


def test_bad_robot_input_is_refused_in_the_worker() -> None:
    async def go() -> None:
        async with Gateway(make_config(workers=1, max_errors=4)) as gw:
            await gw.listen()
            robot = TestRobot(await connector(gw)("demo-robot-0"), 0)
            await robot.hello()
            await robot.send_raw("{bad")
            assert (await robot.error_for(None)).code is ErrorCode.MALFORMED
            ref = await robot.send(State, robot_id=1)
            assert (await robot.error_for(ref)).code is ErrorCode.NOT_YOURSELF
            ref = await robot.send(Finished, action_id="0.1.0")
            assert (await robot.error_for(ref)).code is ErrorCode.NOT_YOURSELF
            await robot.send_raw("{bad")  # the fourth error in a second: closed (1008)
            with pytest.raises(ConnectionClosed) as closed:
                while True:
                    await robot.recv()
            assert closed.value.rcvd is not None and closed.value.rcvd.code == 1008
            with pytest.raises(InvalidStatus):
                await connector(gw)("no-such-token")
            # the worker's counts reach the owner's /metrics with its next ping's answer
            errors = "fleetgate_protocol_errors_total"
            async with asyncio.timeout(10):
                while gw.metrics.value(errors, code="not_yourself") < 2 or gw.metrics.value(
                        "fleetgate_handshakes_refused_total", status="403") < 1:
                    await asyncio.sleep(0.05)
            assert gw.metrics.value(errors, code="malformed") == 2
            assert gw.metrics.value(errors, code="not_yourself") == 2

    asyncio.run(asyncio.wait_for(go(), 60))


def test_tls_and_mutual_tls_end_in_the_workers(tmp_path: Path) -> None:
    certs = make_certs(tmp_path)

    async def go() -> None:
        config = make_config(workers=2, tls=certs.tls())
        async with Gateway(config) as gw:
            port = await gw.listen()
            url = f"wss://127.0.0.1:{port}/ws"
            link = await connect(url, ssl=certs.client(0), proxy=None)  # its certificate
            robot = TestRobot(link, 0)
            assert (await robot.hello()).robot_id == 0
            assert isinstance(gw.engine.robots[0].link, RemoteSession)
            with pytest.raises(InvalidStatus) as refused:  # robot 1's token, robot 0's cert
                await connect(url, ssl=certs.client(0), proxy=None,
                              additional_headers={"Authorization": "Bearer demo-robot-1"})
            assert refused.value.response.status_code == 403
            status, body = await asyncio.to_thread(
                _get, f"https://127.0.0.1:{port}/healthz", certs.client())
            assert status == 200 and json.loads(body)["robots"] == 1

    asyncio.run(asyncio.wait_for(go(), 60))


def test_fuzzing_the_workers_changes_nothing_for_the_fleet(
        tmp_path: Path, capfd: pytest.CaptureFixture[str]) -> None:
    """bench/fuzz.py's hostile frames (robot tokens of ids outside the plan: served by the
    workers; the world and an operator: relayed) while a fleet runs through the workers."""
    stats = FuzzStats()
    source = frames(2000, seed=2)

    async def go() -> None:
        trace = tmp_path / "trace.jsonl"
        config = GatewayConfig(port=0, map=None, policy="none", trace=trace, speed=10.0,
                               autostart=True, workers=2, close_timeout_s=1.0)
        problem = workload(8, 20)
        async with Gateway(config) as gw:
            port = await gw.listen()
            url = f"ws://127.0.0.1:{port}/ws"
            fleet = SimFleet(websocket_connector(url), range(8), clock=gw.clock,
                             send_state=False, reconnect_delay_s=0.05)
            gw.engine.load(problem)
            await fleet.start()
            try:
                await fleet.wait_connected()
                await asyncio.gather(fuzz(url, source, stats, 8, 2), gw.wait_done())
            finally:
                await fleet.stop()
            assert gw.workers is not None and gw.workers.restarts == 0
            assert gw.metrics.value("fleetgate_handler_failures_total") == 0
        report = check_trace(read_trace(trace))
        assert report.ok, report.errors[:5]
        assert report.actions_run == sum(len(p) - 1 for p in problem.plan.paths)

    asyncio.run(asyncio.wait_for(go(), 240))
    assert stats.sent >= 1500
    for code in (ErrorCode.MALFORMED, ErrorCode.INVALID, ErrorCode.UNKNOWN_TYPE,
                 ErrorCode.FORBIDDEN):
        assert stats.replies.get(code.value, 0) > 0, (code, stats.replies)
    assert set(stats.closes) <= {int(c) for c in CloseCode}, stats.closes
    err = capfd.readouterr().err  # the workers' log lines (they share this stderr)
    assert "Traceback" not in err and "handler failed" not in err, err[-2000:]


def test_the_workers_end_with_a_killed_owner_and_free_the_port(tmp_path: Path) -> None:
    """``fleetgate serve --workers 2`` killed with SIGKILL: its workers see their channel
    close and end, so no orphan keeps serving (or holding) the port."""
    env = {**os.environ, "XDG_STATE_HOME": str(tmp_path)}
    env.pop("STATE_DIRECTORY", None)
    owner = subprocess.Popen([sys.executable, "-m", "gateway", "serve", "--port", "0",
                              "--workers", "2", "--no-journal", "--log-level", "WARNING"],
                             stderr=subprocess.PIPE, text=True, env=env)
    try:
        assert owner.stderr is not None
        line = owner.stderr.readline()
        found = re.search(r"ws://127\.0\.0\.1:(\d+)/ws", line)
        assert found, line
        port = int(found[1])
        workers = [c for c in child_pids(owner.pid)
                   if "gateway.server.workers.worker" in
                   Path(f"/proc/{c}/cmdline").read_text().replace("\0", " ")]
        assert len(workers) == 2
        status, _ = _get(f"http://127.0.0.1:{port}/healthz")
        assert status == 200
    finally:
        owner.kill()
        owner.wait(10)
    deadline = time.monotonic() + 20
    while any(Path(f"/proc/{w}").exists() and "Z" not in _state(w) for w in workers):
        assert time.monotonic() < deadline, "a worker outlived its owner"
        time.sleep(0.05)
    with socket.socket() as s:  # nobody listens on the port any more
        assert s.connect_ex(("127.0.0.1", port)) != 0


def _state(pid: int) -> str:
    """The state letter of a process (Z: a zombie, ended)."""
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except OSError:
        return "Z"


def test_a_port_taken_by_another_listener_is_refused_as_without_workers() -> None:
    async def go() -> None:
        with socket.socket() as taken:
            taken.bind(("127.0.0.1", 0))
            taken.listen()
            port = taken.getsockname()[1]
            async with Gateway(make_config(workers=1, port=port)) as gw:
                with pytest.raises(OSError):
                    await gw.listen()
                assert gw.workers is None or gw.workers.pids == []

    asyncio.run(asyncio.wait_for(go(), 60))


def test_a_gateway_in_virtual_time_refuses_workers() -> None:
    """Worker processes cannot share a looptime loop's virtual clock: refused at once with a
    one-line reason, not a start that times out in no virtual time."""
    with pytest.raises(ValueError, match=r"^worker processes run in real time"):
        Gateway(GatewayConfig(port=0, map=None, workers=2), clock=VirtualClock())
