"""The task API over real HTTP on 127.0.0.1: submissions, idempotency, reads, cancel, pause,
refusals, the OpenAPI document (validated, and every answer checked against its schemas), and
the event stream of a shift of simulated robots over websockets. The gateways of the tests
without a running shift run in virtual time."""

from __future__ import annotations

import asyncio
import contextlib
import http.client
import json
import logging
from collections.abc import AsyncIterator
from pathlib import Path
from typing import Any

import jsonschema
import pytest
from openapi_spec_validator import validate as validate_spec

from gateway.planning.grid import Cell, Grid
from gateway.server.clock import VirtualClock, run_virtual
from gateway.server.config import GatewayConfig, LifelongSettings
from gateway.server.gateway import Gateway
from gateway.server.task_api.models import MAX_BATCH, MAX_BODY_BYTES
from gateway.server.task_api.openapi import openapi_document
from sim_clients.connect import websocket_connector
from sim_clients.fleet import SimFleet
from sim_clients.shift import start_shift, stop_shift
from tests.server.task_client import Reply, call, sse
from tests.server.tls_certs import make_certs

ROBOTS = 6


def lifelong_config(**overrides: Any) -> GatewayConfig:
    """A small generated warehouse, tasks only from the API."""
    return GatewayConfig(**{"port": 0, "map": None, "autostart": False, "speed": 10.0,
                            "log_level": "WARNING", "lifelong": LifelongSettings(
                                robots=ROBOTS, warehouse=(2, 3), task_list=False),
                            **overrides})


@contextlib.asynccontextmanager
async def shift_served() -> AsyncIterator[tuple[Gateway, int]]:
    """A lifelong gateway on the test's virtual time whose shift has not started (the pool
    takes tasks already), and its port."""
    async with Gateway(lifelong_config(), clock=VirtualClock()) as gw:
        yield gw, await gw.listen()


def grid_of(gw: Gateway) -> Grid:
    assert gw.engine.lifelong is not None
    return gw.engine.lifelong.shift.grid


def cells(gw: Gateway, n: int) -> list[list[int]]:
    return [list(c) for c in list(grid_of(gw).free_cells())[:n]]


SPEC = openapi_document()


def check_schema(reply: Reply, operation: tuple[str, str]) -> None:
    """The reply's body matches the OpenAPI document's schema for its status (an oracle
    independent of the pydantic models that produced the body)."""
    path, method = operation
    responses = SPEC["paths"][path][method]["responses"]
    described = responses.get(str(reply.status)) or (
        responses.get("default") if reply.status >= 400 else None)
    assert described is not None, f"{reply.status} not documented for {operation}"
    schema = described["content"]["application/json"]["schema"]
    jsonschema.validate(reply.json(), {**schema, "components": SPEC["components"]})


@pytest.mark.looptime  # virtual time over real HTTP
async def test_submit_retry_read_cancel_pause() -> None:
    async with shift_served() as (gw, port):
        a, b, c = cells(gw, 3)
        batch = {"tasks": [{"errands": [a, b]}, {"errands": [c], "priority": 3,
                                                 "deadline_ms": 90_000}]}
        first = await call(port, "POST", "/tasks", batch, {"Authorization": "Bearer demo-operator",
                                                           "Idempotency-Key": "wms-1"})
        check_schema(first, ("/tasks", "post"))
        assert first.status == 201 and first.json()["created"] is True
        ids = [t["id"] for t in first.json()["tasks"]]
        assert first.json()["tasks"][0]["errands"] == [a, b]
        assert first.json()["tasks"][1]["priority"] == 3
        # the retry (key in the body this time) creates nothing
        retry = await call(port, "POST", "/tasks", {**batch, "idempotency_key": "wms-1"})
        assert retry.status == 200 and [t["id"] for t in retry.json()["tasks"]] == ids
        check_schema(retry, ("/tasks", "post"))
        other = await call(port, "POST", "/tasks", {"errands": [a], "idempotency_key": "wms-1"})
        assert other.status == 409
        assert other.json() == {"error": f"idempotency key 'wms-1' was used for a different "
                                         f"request (tasks {ids[0]}, {ids[1]})"}
        check_schema(other, ("/tasks", "post"))
        one = await call(port, "POST", "/tasks", {"errands": [c]})
        assert one.status == 201 and one.json()["tasks"][0]["id"] == ids[1] + 1
        # reads
        got = await call(port, "GET", f"/tasks/{ids[0]}")
        check_schema(got, ("/tasks/{id}", "get"))
        assert got.json()["state"] == "queued" and got.json()["idempotency_key"] == "wms-1"
        page = await call(port, "GET", "/tasks?state=queued&limit=2")
        check_schema(page, ("/tasks", "get"))
        body = page.json()
        assert [t["id"] for t in body["tasks"]] == ids and body["next_after"] == ids[1]
        assert body["counts"]["queued"] == 3
        rest = await call(port, "GET", f"/tasks?after={ids[1]}")
        assert [t["id"] for t in rest.json()["tasks"]] == [ids[1] + 1]
        assert rest.json()["next_after"] is None
        # pause, resume, cancel (twice: a retried DELETE changes nothing)
        paused = await call(port, "POST", f"/tasks/{ids[0]}/pause")
        check_schema(paused, ("/tasks/{id}/pause", "post"))
        assert paused.json()["task"]["state"] == "paused"
        assert (await call(port, "GET", "/tasks?state=paused")).json()["tasks"][0]["id"] == ids[0]
        resumed = await call(port, "POST", f"/tasks/{ids[0]}/resume")
        assert resumed.json()["task"]["state"] == "queued"
        for _ in range(2):
            gone = await call(port, "DELETE", f"/tasks/{ids[0]}")
            check_schema(gone, ("/tasks/{id}", "delete"))
            assert gone.status == 200 and gone.json()["state"] == "cancelled"
        again = await call(port, "POST", f"/tasks/{ids[0]}/resume")
        assert again.status == 409 and again.json()["error"] == (
            f"task {ids[0]} is cancelled: it cannot be resumed")


@pytest.mark.looptime  # virtual time over real HTTP
async def test_refusals_are_precise() -> None:
    async with shift_served() as (gw, port):
        grid = grid_of(gw)
        (a,) = cells(gw, 1)
        blocked = next((x, y) for y in range(grid.height) for x in range(grid.width)
                       if not grid.is_free((x, y)))
        cases: list[tuple[tuple[str, str, Any, dict[str, str] | None, bytes | None], int, str]] = [
            (("POST", "/tasks", {"errands": [a]}, {}, None), 401, "missing token"),
            (("GET", "/tasks", None, {"Authorization": "Bearer demo-robot-1"}, None), 403,
             "not an operator token"),
            (("GET", "/tasks", None, {"Authorization": "Bearer nobody"}, None), 403,
             "unknown token"),
            (("POST", "/tasks", None, None, b"{nope"), 415, "application/json"),
            (("POST", "/tasks", None, {"Authorization": "Bearer demo-operator",
                                       "Content-Type": "application/json"}, b"{nope"), 400,
             "not JSON"),
            (("POST", "/tasks", [1, 2], None, None), 400, "must be a JSON object"),
            (("POST", "/tasks", {"errands": []}, None, None), 400, "errands: List should have"),
            (("POST", "/tasks", {"errands": [a], "colour": "red"}, None, None), 400,
             "colour: Extra inputs are not permitted"),
            (("POST", "/tasks", {"errands": [list(blocked)]}, None, None), 422,
             f"errands.0: {list(blocked)} is not a free cell of the map"),
            (("POST", "/tasks", {"tasks": [{"errands": [a]}, {"errands": [[a[0], 10**5]]}]},
              None, None), 422, "tasks.1.errands.0"),
            (("POST", "/tasks", {"tasks": [{"errands": [a]}] * (MAX_BATCH + 1)}, None, None), 400,
             f"at most {MAX_BATCH} items"),
            (("POST", "/tasks", {"errands": [a], "priority": 10**40}, None, None), 413,
             "more than 32 digits"),
            (("POST", "/tasks", {"errands": [a], "idempotency_key": "x" * 200}, None, None), 400,
             "idempotency_key"),
            (("POST", "/tasks", None, None, b"[" * 50 + b"]" * 50), 413, "nested deeper"),
            (("POST", "/tasks", {"errands": [a]}, {"Authorization": "Bearer demo-operator",
                                                   "Idempotency-Key": "two words"}, None), 400,
             "Idempotency-Key: String should match pattern"),
            (("POST", "/tasks", {"errands": [a]}, {"Authorization": "Bearer demo-operator",
                                                   "Idempotency-Key": "x" * 129}, None), 400,
             "Idempotency-Key: String should have at most 128 characters"),
            (("POST", "/tasks", {"errands": [a], "idempotency_key": "b"},
              {"Authorization": "Bearer demo-operator", "Idempotency-Key": "a"}, None), 400,
             "the Idempotency-Key header and the idempotency_key field differ"),
            (("POST", "/tasks?colour=1", {"errands": [a]}, None, None), 400,
             "unknown query parameter 'colour' (known: none)"),
            (("GET", "/tasks/999", None, None, None), 404, "no task 999"),
            (("DELETE", "/tasks/999", None, None, None), 404, "no task 999"),
            (("GET", "/tasks?state=lost", None, None, None), 400, "unknown state 'lost'"),
            (("GET", "/tasks?limit=0", None, None, None), 400,
             "limit: Input should be greater than or equal to 1"),
            (("GET", "/tasks?colour=1", None, None, None), 400, "unknown query parameter"),
            (("PUT", "/tasks/1", None, None, b"{}"), 405, "use GET or DELETE"),
            (("GET", "/tasks/1/pause", None, None, None), 405, "GET /tasks/1/pause: use POST"),
            (("GET", "/tasks/x/y", None, None, None), 404, "no route"),
        ]
        for (method, path, data, headers, raw), status, words in cases:
            if raw is not None and headers is None and status != 415:
                headers = {"Authorization": "Bearer demo-operator",
                           "Content-Type": "application/json"}
            reply = await call(port, method, path, data, headers, raw)
            assert reply.status == status, (method, path, reply.status, reply.body[:200])
            error = reply.json()["error"]
            assert words in error and "\n" not in error, (path, error)
        # a body over the limit is refused before it is read
        big = await call(port, "POST", "/tasks", None, None, b" " * (MAX_BODY_BYTES + 1))
        assert big.status == 413 and "more than" in big.json()["error"]
        # a GUI login may read, and change only from the gateway's own origin
        login = await call(port, "GET", "/session", headers={"Authorization":
                                                             "Bearer demo-operator"})
        cookie = login.headers["set-cookie"].split(";")[0]
        assert (await call(port, "GET", "/tasks", headers={"Cookie": cookie})).status == 200
        foreign = await call(port, "POST", "/tasks", {"errands": [a]},
                             {"Cookie": cookie, "Origin": "http://evil.example"})
        assert foreign.status == 403 and "Origin" in foreign.json()["error"]
        own = await call(port, "POST", "/tasks", {"errands": [a]},
                         {"Cookie": cookie, "Origin": f"http://127.0.0.1:{port}"})
        assert own.status == 201
        pool = gw.engine.current_run.tasks
        assert pool is not None and pool.next_id == 1  # nothing else made


@pytest.mark.looptime  # virtual time over real HTTP
async def test_openapi_document_is_served_valid_and_complete() -> None:
    async with shift_served() as (_, port):
        reply = await call(port, "GET", "/openapi.json", headers={})  # public: no secret in it
        assert reply.status == 200
        doc = reply.json()
        validate_spec(doc)
        assert doc == json.loads(json.dumps(openapi_document()))
        assert set(doc["paths"]) == {"/tasks", "/tasks/{id}", "/tasks/{id}/pause",
                                     "/tasks/{id}/resume", "/tasks/events"}
        # every schema the document names is defined there
        text = json.dumps(doc)
        for name in {part.split('"')[0] for part in text.split("#/components/schemas/")[1:]}:
            assert name in doc["components"]["schemas"], name


def test_no_lifelong_mode_no_task_pool() -> None:
    async def main() -> Reply:
        async with Gateway(GatewayConfig(port=0, log_level="WARNING"),
                           clock=VirtualClock()) as gw:
            return await call(await gw.listen(), "GET", "/tasks")

    reply = run_virtual(main())
    assert reply.status == 503 and "not in lifelong mode" in reply.json()["error"]


def test_tasks_finish_once_and_the_stream_tells_every_change(tmp_path: Path) -> None:
    """A shift of simulated robots over websockets does submitted tasks; the event stream,
    read by two clients (one reconnecting with Last-Event-ID), shows each task's changes in
    a valid order and its finish once; a started task cannot be cancelled."""
    out: dict[str, Any] = {}

    async def main() -> None:
        async with Gateway(lifelong_config(trace=tmp_path / "trace.jsonl")) as gw:
            port = await gw.listen()
            free: list[Cell] = list(grid_of(gw).free_cells())
            fleet = SimFleet(websocket_connector(f"ws://127.0.0.1:{port}/ws"), range(ROBOTS),
                             clock=gw.clock, send_state=False)
            await start_shift(gw, fleet)
            stream = sse(port, "/tasks/events?after=0")
            tasks = [{"errands": [list(free[(7 * k) % len(free)]),
                                  list(free[(13 * k + 5) % len(free)])]} for k in range(12)]
            submitted = await call(port, "POST", "/tasks", {"tasks": tasks})
            ids = [t["id"] for t in submitted.json()["tasks"]]
            events: list[Any] = []
            finished: set[int] = set()
            refused_started = ""
            cut = None
            async with asyncio.timeout(120):
                async for ev in stream:
                    events.append(ev)
                    data = ev.data
                    if data["state"] == "started" and not refused_started:
                        reply = await call(port, "DELETE", f"/tasks/{data['task']}")
                        refused_started = reply.json()["error"] if reply.status == 409 else ""
                    if data["state"] == "finished":
                        finished.add(data["task"])
                        if cut is None:
                            cut = ev.id
                    if finished == set(ids):
                        break
            await stream.aclose()
            # a second client resumes after the first finish and gets exactly the rest
            resumed = []
            async with asyncio.timeout(30):
                async for ev in sse(port, headers={"Last-Event-ID": str(cut)}):
                    resumed.append(ev)
                    if ev.id == events[-1].id:
                        break
            out["stats"] = await stop_shift(gw, fleet)
            await fleet.stop()
            # the shift is over: a new task would never run, so none is taken
            out["late"] = await call(port, "POST", "/tasks", {"tasks": tasks[:1]})
            out.update(events=events, resumed=resumed, cut=cut, ids=ids,
                       refused=refused_started)

    asyncio.run(main())
    events, ids = out["events"], out["ids"]
    assert [e.id for e in out["resumed"]] == [e.id for e in events if e.id > out["cut"]]
    assert [e.id for e in events] == list(range(1, len(events) + 1))
    by_task: dict[int, list[str]] = {}
    for e in events:
        assert e.event == "task" and e.id == e.data["seq"]
        by_task.setdefault(e.data["task"], []).append(e.data["state"])
    assert sorted(by_task) == ids
    allowed = {None: {"queued"}, "queued": {"assigned"}, "assigned": {"queued", "assigned",
                                                                      "started", "finished"},
               "started": {"started", "finished"}}
    for task, states in by_task.items():
        assert states.count("finished") == 1, (task, states)
        prev = None
        for s in states:
            assert s in allowed[prev], (task, states)
            prev = s
    assert "is started" in out["refused"] and "cannot be cancelled" in out["refused"]
    assert (out["late"].status, out["late"].json()) == (
        409, {"error": "the shift has ended: no new task would run"})
    stats = out["stats"]
    assert stats.finished_tasks == len(ids)
    assert stats.lost == 0 and stats.duplicated == 0 and stats.collisions == 0


def test_docs_tasks_md_is_up_to_date() -> None:
    """docs/tasks.md is what ``python -m gateway.server.task_api.openapi`` renders now."""
    from gateway.server.task_api.openapi import markdown

    doc = Path(__file__).resolve().parents[2] / "docs" / "tasks.md"
    assert doc.read_text() == markdown(), \
        "docs/tasks.md is stale: python -m gateway.server.task_api.openapi > docs/tasks.md"


def test_the_task_api_over_tls(tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    """Submit, read and stream over HTTPS with the gateway's CA; nothing is logged for it
    (asyncio warned on every request that TLS has no half-close)."""
    certs = make_certs(tmp_path)
    context = certs.client()

    def request(port: int, method: str, path: str, body: Any = None) -> tuple[int, bytes]:
        conn = http.client.HTTPSConnection("127.0.0.1", port, context=context, timeout=10)
        try:
            conn.request(method, path, None if body is None else json.dumps(body),
                         {"Authorization": "Bearer demo-operator",
                          "Content-Type": "application/json"})
            reply = conn.getresponse()
            stream = reply.getheader("Content-Type") == "text/event-stream"
            return reply.status, reply.read(60) if stream else reply.read()
        finally:
            conn.close()

    async def main() -> list[tuple[int, bytes]]:
        async with Gateway(lifelong_config(tls=certs.tls())) as gw:
            port = await gw.listen()
            (cell,) = cells(gw, 1)
            out = []
            for args in (("POST", "/tasks", {"errands": [cell]}), ("GET", "/tasks/0"),
                         ("GET", "/tasks/events?after=0"), ("POST", "/healthz", {})):
                out.append(await asyncio.to_thread(request, port, *args))
            return out

    with caplog.at_level(logging.WARNING):
        made, got, events, plain = asyncio.run(main())
    assert made[0] == 201 and got[0] == 200 and json.loads(got[1])["id"] == 0
    assert events[0] == 200 and b"id: 1\nevent: task\n" in events[1]
    assert plain == (405, b'{"error": "POST /healthz: only GET is served here"}')
    assert [r.getMessage() for r in caplog.records] == []
