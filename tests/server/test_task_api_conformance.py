"""The task API as a warehouse system's vendor meets it: ``fleetgate serve`` in lifelong mode in
a child process, plain HTTP on 127.0.0.1, and the OpenAPI document it serves as the oracle.

Hypothesis sends requests of every kind (methods, paths, ids, queries, credentials, content
types, bodies valid and not); each answer must be one the document describes for its route
(status, JSON body conforming to its schema), a wrong method a 405 naming the documented ones,
and a submission must be accepted exactly when its body is valid under the document's request
schema (integers strictly integers) and its cells are free cells of the map, with the
idempotency key behaving as a model of it says (same request: the same ids; another: 409).
Around it: the plain routes take only GET, ``Expect: 100-continue`` is honoured (after the
credentials, before the body), a stranger's body is never read, concurrent
retries of one key create its tasks once, and no page or answer an unauthenticated client can
read, nor the gateway's log, holds the operator's token.
"""

from __future__ import annotations

import asyncio
import itertools
import json
import secrets
import socket
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any
from urllib.parse import urlencode

import jsonschema
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from openapi_spec_validator import validate as validate_spec

from bench.crash import GatewayProcess, free_port
from gateway.planning.lorr import warehouse_problem
from gateway.web import __file__ as web_init
from tests.server.task_client import Reply, Sse, call, sse

ROBOTS = 3
TOKEN = secrets.token_urlsafe(24)
AUTH = {"Authorization": f"Bearer {TOKEN}"}
GRID = warehouse_problem(ROBOTS, 0, (2, 3), p_delay=0.0).grid
FREE = [[x, y] for x, y in GRID.free_cells()]
BLOCKED = [[x, y] for y in range(GRID.height) for x in range(GRID.width)
           if not GRID.is_free((x, y))]
TEMPLATES = ("/tasks", "/tasks/{id}", "/tasks/{id}/pause", "/tasks/{id}/resume")
CREDENTIALS: list[tuple[dict[str, str], int | None]] = [
    (AUTH, None), ({}, 401), ({"Authorization": "Bearer demo-robot-1"}, 403),
    ({"Authorization": f"Bearer not-{TOKEN}"}, 403), ({"Authorization": "Basic eDp5"}, 401)]
"""Credentials a request may carry, and the refusal they get (None: the operator's)."""


@dataclass
class Served:
    """The gateway process, its OpenAPI document, and a model of what was created."""

    gw: GatewayProcess = field(repr=False)
    spec: dict[str, Any] = field(repr=False)
    keys: dict[str, tuple[Any, list[int]]]
    """Idempotency key -> the tasks it created (errands, priority, deadline) and their ids."""
    errands: dict[int, list[list[int]]] = field(repr=False)
    """Task id -> its errands, for every task created."""

    @property
    def port(self) -> int:
        """The gateway's port."""
        return self.gw.port


@pytest.fixture(scope="module")
def served(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Served]:
    """``fleetgate serve`` in lifelong mode with a secret operator token (no robots: every
    task stays queued)."""
    work = tmp_path_factory.mktemp("conformance")
    gw = GatewayProcess(work, free_port(), speed=10.0, policy="none")
    gw.config.write_text(json.dumps({
        **json.loads(gw.config.read_text()), "map": None, "autostart": False,
        "tokens": {"operators": [TOKEN]}, "log_level": "INFO",
        "lifelong": {"robots": ROBOTS, "warehouse": [2, 3], "task_list": False}}))
    gw.cmd[gw.cmd.index("--log-level") + 1] = "INFO"
    gw.start()
    try:
        spec = asyncio.run(call(gw.port, "GET", "/openapi.json", headers={})).json()
        validate_spec(spec)
        yield Served(gw, spec, {}, {})
    finally:
        gw.stop()


def _strict_validator(schema: dict[str, Any], spec: dict[str, Any]) -> jsonschema.Validator:
    """A validator of ``schema`` (refs into ``spec``) for which an integer is a JSON integer
    (neither 1.0 nor true), as the gateway reads them."""
    base = jsonschema.Draft202012Validator
    checker = base.TYPE_CHECKER.redefine(
        "integer", lambda _, v: isinstance(v, int) and not isinstance(v, bool))
    strict = jsonschema.validators.extend(base, type_checker=checker)
    return strict({**schema, "components": spec["components"]})


def check_described(spec: dict[str, Any], template: str, method: str, reply: Reply) -> None:
    """The reply is what the document says ``method template`` answers: a documented status
    (or ``default``), JSON conforming to its schema; a method the route lacks is a 405."""
    ops = spec["paths"][template]
    if method.lower() not in ops:
        assert reply.status in (401, 403, 405), (method, template, reply.status, reply.body)
        if reply.status == 405:
            allowed = {m.strip() for m in reply.headers["allow"].split(",")}
            assert allowed == {m.upper() for m in ops}, (template, allowed)
        return
    responses = ops[method.lower()]["responses"]
    described = responses.get(str(reply.status)) or (
        responses.get("default") if reply.status >= 400 else None)
    assert described is not None, (method, template, reply.status, reply.body[:200])
    assert reply.headers["content-type"] == "application/json"
    body = reply.json()
    _strict_validator(described["content"]["application/json"]["schema"], spec).validate(body)
    if reply.status >= 400:
        assert body["error"] and "\n" not in body["error"] and len(body["error"]) < 300
    if reply.status == 401:
        assert reply.headers.get("www-authenticate") == "Bearer"


# ---------------------------------------------------------------------- strategies
_json_leaf = st.one_of(st.none(), st.booleans(), st.integers(-10**6, 10**6),
                       st.floats(allow_nan=False, allow_infinity=False, width=32),
                       st.text(max_size=6))
_odd: st.SearchStrategy[Any] = st.sampled_from(
    ["5", True, False, 1.0, 2.5, None, [], {}, -1, 10**7, "x"])
"""Values of the wrong type or range for some field."""


@st.composite
def _task(draw: st.DrawFn) -> dict[str, Any]:
    """A valid task, or one with one thing wrong (a field's type or range, a cell off the map
    or in a wall, no errands, an unknown field)."""
    task: dict[str, Any] = draw(st.fixed_dictionaries(
        {"errands": st.lists(st.sampled_from(FREE).map(list), min_size=1, max_size=3)},
        optional={"priority": st.integers(-1000, 1000),
                  "deadline_ms": st.one_of(st.floats(0, 1e6), st.integers(0, 10**6))}))
    match draw(st.integers(0, 6)):
        case 1:
            task[draw(st.sampled_from(["priority", "deadline_ms"]))] = draw(_odd)
        case 2:
            cell = draw(st.sampled_from(task["errands"]))
            cell[draw(st.integers(0, 1))] = draw(_odd)
        case 3:
            task["errands"].append(draw(st.one_of(
                st.sampled_from(BLOCKED), st.lists(st.integers(0, 60), min_size=2, max_size=2),
                st.lists(_json_leaf, max_size=3))))
        case 4:
            task["errands"] = draw(st.one_of(st.just([]), _odd))
        case 5:
            task[draw(st.sampled_from(["colour", "Errands", "id"]))] = draw(_json_leaf)
    return task


_key = st.text(st.sampled_from("ab1-_ é"), min_size=0, max_size=4)
_body = st.one_of(
    _task(), _task(), _task(),
    st.tuples(_task(), _key).map(lambda tk: {**tk[0], "idempotency_key": tk[1]}),
    st.fixed_dictionaries({"tasks": st.lists(_task(), max_size=3)},
                          optional={"idempotency_key": _key}),
    st.lists(_json_leaf, max_size=2), _json_leaf)
_id = st.one_of(st.integers(0, 40).map(str), st.integers(-5, 10**20).map(str),
                st.text(st.sampled_from("x%0-."), min_size=1, max_size=4))
_query = st.dictionaries(
    st.sampled_from(["state", "robot", "after", "limit", "colour"]),
    st.one_of(st.sampled_from(["queued", "finished,queued", "lost", ""]),
              st.integers(-3, 2000).map(str), st.text(st.sampled_from("a1-"), max_size=3)),
    max_size=3)


Request = tuple[str, str, str, dict[str, str], Any, bytes | None, int | None]


@st.composite
def requests(draw: st.DrawFn) -> Request:
    """A request: method, route template, path, headers, JSON body (or raw bytes), and the
    refusal its credentials get (None: the operator's)."""
    submit = draw(st.booleans())  # half of them: POST /tasks
    template = "/tasks" if submit else draw(st.sampled_from(TEMPLATES))
    method = "POST" if submit else draw(st.sampled_from(["GET", "POST", "DELETE", "PUT",
                                                         "PATCH"]))
    path = template.replace("{id}", draw(_id))
    if template == "/tasks" and method == "GET":
        path += "?" + urlencode(draw(_query)) if draw(st.booleans()) else ""
    credentials, refusal = draw(st.sampled_from(CREDENTIALS[:1] * 4 + CREDENTIALS))
    headers = dict(credentials)
    ctype = draw(st.sampled_from(["application/json", "application/json; charset=utf-8",
                                  "text/plain", None]))
    if ctype is not None:
        headers["Content-Type"] = ctype
    if draw(st.booleans()) and method == "POST":
        headers["Idempotency-Key"] = draw(st.text(st.sampled_from("ab1-"), min_size=1,
                                                  max_size=3))
    if draw(st.integers(0, 9)) == 0:
        return method, template, path, headers, None, draw(st.binary(max_size=20)), refusal
    body = draw(_body) if method == "POST" else None
    return method, template, path, headers, body, None, refusal


def _normalised(body: dict[str, Any]) -> Any:
    """What the gateway compares when a key comes again: each task's errands, priority and
    deadline (defaults filled in)."""
    return [(t["errands"], t.get("priority", 0),
             None if t.get("deadline_ms") is None else float(t["deadline_ms"]))
            for t in body.get("tasks", [body])]


def _expected_submission(served: Served, headers: dict[str, str], data: Any,
                         raw: bytes | None) -> set[int]:
    """The statuses the document and the model allow for a POST /tasks by the operator."""
    if not headers.get("Content-Type", "").startswith("application/json"):
        return {415}
    if raw is not None:
        return {400, 413}
    request = served.spec["paths"]["/tasks"]["post"]["requestBody"]["content"][
        "application/json"]["schema"]
    if not _strict_validator(request, served.spec).is_valid(data):
        return {400, 413}
    body_key = data.get("idempotency_key")
    header_key = headers.get("Idempotency-Key")
    if body_key is not None and header_key is not None and body_key != header_key:
        return {400}
    if any(not GRID.is_free((c[0], c[1])) for t in data.get("tasks", [data])
           for c in t["errands"]):
        return {422}
    key = header_key or body_key
    if key in served.keys:
        return {200} if served.keys[key][0] == _normalised(data) else {409}
    return {201}


@settings(max_examples=250, deadline=None)
@given(request=requests())
def test_every_answer_is_described_and_submissions_follow_the_document(
        served: Served, request: Request) -> None:
    method, template, path, headers, data, raw, refusal = request
    if data is not None:  # as call() sends it
        headers.setdefault("Content-Type", "application/json")
    expected = None if refusal is None else {refusal}
    if refusal is None and template == "/tasks" and method == "POST":
        expected = _expected_submission(served, headers, data, raw)
    reply = asyncio.run(call(served.port, method, path, data, headers, raw))
    if reply.status == 201:  # the model learns what the gateway made first (shrinking replays)
        made = reply.json()["tasks"]
        key = headers.get("Idempotency-Key") or data.get("idempotency_key")
        if key is not None:
            served.keys[key] = ([(t["errands"], t["priority"], t["deadline_ms"]) for t in made],
                                [t["id"] for t in made])
        served.errands.update({t["id"]: t["errands"] for t in made})
    check_described(served.spec, template, method, reply)
    if expected is not None:
        assert reply.status in expected, (method, path, headers, data, raw, reply.status,
                                          reply.body[:300])
    if reply.status == 200 and method == "POST" and template == "/tasks":
        key = headers.get("Idempotency-Key") or data.get("idempotency_key")
        assert [t["id"] for t in reply.json()["tasks"]] == served.keys[key][1]
    if reply.status == 200 and method == "GET" and template == "/tasks/{id}":
        task = reply.json()
        assert task["errands"] == served.errands[task["id"]]


def test_plain_routes_answer_only_get(served: Served) -> None:
    async def main() -> list[tuple[str, str, Reply]]:
        return [(method, path, await call(served.port, method, path, {"x": 1}, headers={}))
                for method in ("POST", "PUT", "DELETE", "PATCH")
                for path in ("/", "/healthz", "/readyz", "/metrics", "/openapi.json",
                             "/session", "/login", "/ws")]

    for method, path, reply in asyncio.run(main()):
        assert reply.status == 405, (method, path, reply.status)
        assert reply.headers["allow"] == "GET"
        assert reply.json() == {"error": f"{method} {path}: only GET is served here"}


def _raw_exchange(port: int, head: str, body: bytes) -> tuple[bytes, bytes]:
    """Send a request head, read what comes before the body is sent (within 2 s), then send
    the body and read the rest."""
    with socket.create_connection(("127.0.0.1", port), timeout=10) as sock:
        sock.sendall(head.encode())
        sock.settimeout(2.0)
        try:
            early = sock.recv(4096)
        except TimeoutError:
            early = b""
        sock.settimeout(10)
        if not early.startswith(b"HTTP/1.1 4"):
            sock.sendall(body)
        rest = b""
        while chunk := sock.recv(65536):
            rest += chunk
        return early, rest


def test_expect_100_continue_is_answered_before_the_body(served: Served) -> None:
    body = json.dumps({"errands": [FREE[3]]}).encode()
    head = (f"POST /tasks HTTP/1.1\r\nHost: 127.0.0.1\r\nAuthorization: Bearer {TOKEN}\r\n"
            f"Content-Type: application/json\r\nContent-Length: {len(body)}\r\n"
            "Connection: close\r\n")
    early, rest = _raw_exchange(served.port, head + "Expect: 100-continue\r\n\r\n", body)
    assert early == b"HTTP/1.1 100 Continue\r\n\r\n"  # not after a timeout
    assert rest.startswith(b"HTTP/1.1 201 Created\r\n")
    served.errands.update({t["id"]: t["errands"] for t in json.loads(
        rest.split(b"\r\n\r\n", 1)[1])["tasks"]})
    early, rest = _raw_exchange(served.port, head + "Expect: magic\r\n\r\n", body)
    assert early.startswith(b"HTTP/1.1 417 Expectation Failed\r\n")
    assert b'{"error": "unsupported Expect: magic (only 100-continue)"}' in early + rest


def test_concurrent_retries_of_one_key_create_the_tasks_once(served: Served) -> None:
    batch = {"tasks": [{"errands": [FREE[5], FREE[9]]}, {"errands": [FREE[7]]}]}
    key = {"Idempotency-Key": "retry-" + secrets.token_hex(4), **AUTH}

    async def main() -> tuple[list[Reply], int, int]:
        before = (await call(served.port, "GET", "/tasks?limit=1", headers=AUTH)).json()
        replies = await asyncio.gather(*(call(served.port, "POST", "/tasks", batch, key)
                                         for _ in range(12)))
        after = (await call(served.port, "GET", "/tasks?limit=1", headers=AUTH)).json()
        return list(replies), sum(before["counts"].values()), sum(after["counts"].values())

    replies, before, after = asyncio.run(main())
    assert sorted(r.status for r in replies) == [200] * 11 + [201]
    ids = {tuple(t["id"] for t in r.json()["tasks"]) for r in replies}
    assert len(ids) == 1 and after - before == 2
    served.errands.update({t["id"]: t["errands"] for t in replies[0].json()["tasks"]})


def test_nothing_an_unauthenticated_client_reads_holds_the_token(served: Served) -> None:
    static = Path(web_init).resolve().parent / "static"
    paths = ["/", "/login", "/session", "/logout", "/healthz", "/readyz", "/metrics",
             "/openapi.json", "/ws", "/tasks", "/tasks/0", "/tasks/events", "/tasks/0/pause",
             *(f"/{f.name}" for f in static.iterdir())]

    async def main() -> list[Reply]:
        out = [await call(served.port, "GET", p, headers={}) for p in paths]
        # refused credentials are not echoed either
        out.append(await call(served.port, "GET", "/tasks",
                              headers={"Authorization": f"Bearer {TOKEN}x"}))
        return out

    replies = asyncio.run(main())
    assert [r.status for r in replies[:3]] == [200, 200, 401]
    for path, reply in zip([*paths, "/tasks (refused)"], replies, strict=True):
        text = reply.body.decode("utf-8", "replace") + json.dumps(reply.headers)
        assert TOKEN not in text and TOKEN[:12] not in text, path
    served.gw.log.flush()
    assert TOKEN[:12] not in served.gw.log_path.read_text()


def test_the_event_stream_is_as_described(served: Served) -> None:
    """Every event so far comes once, in order, with its id, and conforms to the schema the
    document names for the stream's data; a bad Last-Event-ID is a described 400."""
    stream = served.spec["paths"]["/tasks/events"]["get"]["responses"]["200"]["content"]
    validator = _strict_validator(
        stream["text/event-stream"]["schema"]["properties"]["data"]["contentSchema"], served.spec)

    async def main() -> tuple[int, list[Sse], Reply]:
        assert (await call(served.port, "POST", "/tasks", {"errands": [FREE[2]]},
                           AUTH)).status == 201
        last = (await call(served.port, "GET", "/tasks?limit=1", headers=AUTH)).json()
        events = []
        async with asyncio.timeout(30):
            async for ev in sse(served.port, "/tasks/events?after=0", AUTH):
                events.append(ev)
                if ev.id == last["last_event"]:
                    break
        bad = await call(served.port, "GET", "/tasks/events", headers={
            **AUTH, "Last-Event-ID": "yesterday"})
        return last["last_event"], events, bad

    last, events, bad = asyncio.run(main())
    assert [e.id for e in events] == list(range(1, last + 1))
    for ev in events:
        assert ev.event == "task" and ev.data["seq"] == ev.id
        validator.validate(ev.data)
    check_described(served.spec, "/tasks/events", "GET", bad)
    assert bad.status == 400 and "Last-Event-ID" in bad.json()["error"]


def _exchange(port: int, pieces: list[bytes]) -> bytes:
    """Send a request in pieces (each its own segment, most likely) and read the answer."""
    with socket.create_connection(("127.0.0.1", port), timeout=10) as sock:
        for piece in pieces:
            sock.sendall(piece)
            time.sleep(0.005)
        answer = b""
        while chunk := sock.recv(65536):
            answer += chunk
        return answer


CHUNKED_HEAD = (f"POST /tasks HTTP/1.1\r\nHost: 127.0.0.1\r\nAuthorization: Bearer {TOKEN}\r\n"
                f"Content-Type: application/json\r\nConnection: close\r\n").encode()


@settings(max_examples=20, deadline=None)
@given(cuts=st.lists(st.integers(0, 80), max_size=5), split=st.integers(0, 400))
def test_a_chunked_body_is_read_as_a_whole(served: Served, cuts: list[int], split: int) -> None:
    """``Transfer-Encoding: chunked`` (Node's and .NET's streamed bodies): a body cut into
    any chunks, sent in two pieces cut anywhere, is the same submission."""
    body = json.dumps({"errands": [FREE[11], FREE[12]], "priority": 2}).encode()
    bounds = sorted({min(c, len(body)) for c in cuts} | {0, len(body)})
    wire = CHUNKED_HEAD + b"Transfer-Encoding: chunked\r\n\r\n" + b"".join(
        f"{b - a:x};ext=1\r\n".encode() + body[a:b] + b"\r\n"
        for a, b in itertools.pairwise(bounds)) + b"0\r\nX-Trailer: t\r\n\r\n"
    answer = _exchange(served.port, [wire[:split], wire[split:]])
    assert answer.startswith(b"HTTP/1.1 201 Created\r\n"), answer[:300]
    made = json.loads(answer.split(b"\r\n\r\n", 1)[1])["tasks"]
    assert [(t["errands"], t["priority"]) for t in made] == [([FREE[11], FREE[12]], 2)]
    served.errands[made[0]["id"]] = made[0]["errands"]


def test_a_strangers_trickled_body_is_never_read(served: Served) -> None:
    """A chunked body of one-byte chunks without credentials (it cost minutes of event-loop
    CPU when bodies were read before authorisation): refused 401 on its head, at once."""
    head = (b"POST /tasks HTTP/1.1\r\nHost: 127.0.0.1\r\nContent-Type: application/json\r\n"
            b"Transfer-Encoding: chunked\r\n\r\n")
    with socket.create_connection(("127.0.0.1", served.port), timeout=10) as sock:
        sock.sendall(head + b"1\r\nX\r\n" * 10)
        t0 = time.monotonic()
        answer = sock.recv(4096)
        waited = time.monotonic() - t0
        assert answer.startswith(b"HTTP/1.1 401 Unauthorized\r\n"), answer[:200]
        assert waited < 2.0
        for _ in range(50):  # what it sends next is never answered again
            try:
                sock.sendall(b"1\r\nX\r\n")
            except OSError:
                break
            time.sleep(0.001)


@pytest.mark.parametrize(("coding", "body", "status", "error"), [
    ("chunked", b"zz\r\n{}\r\n0\r\n\r\n", 400, None),
    ("chunked", b"2\r\n{}}\r\n0\r\n\r\n", 400, None),
    ("chunked", b"40001\r\n" + b" " * 0x40001 + b"\r\n0\r\n\r\n", 413,
     "the body has more than 262144 bytes"),
    ("chunked\r\nContent-Length: 2", b"{}", 400, None),
])
def test_a_bad_transfer_coding_is_refused(served: Served, coding: str, body: bytes,
                                          status: int, error: str | None) -> None:
    """Malformed chunks and a body with both lengths are the HTTP server's 400 (httptools);
    a body over the limit is the API's 413."""
    answer = _exchange(served.port, [CHUNKED_HEAD + f"Transfer-Encoding: {coding}\r\n\r\n"
                                     .encode() + body])
    assert answer.startswith(f"HTTP/1.1 {status} ".encode()), answer[:200]
    if error is not None:
        assert json.loads(answer.split(b"\r\n\r\n", 1)[1]) == {"error": error}


def test_an_event_id_the_gateway_never_gave_resets_the_stream(served: Served) -> None:
    """A WMS that kept a Last-Event-ID from another shift (a fresh journal) is told to re-read
    the tasks, then gets the events from now on: none is skipped silently."""
    async def main() -> tuple[list[Sse], int]:
        last = (await call(served.port, "GET", "/tasks?limit=1", headers=AUTH)).json()
        got: list[Sse] = []
        async with asyncio.timeout(30):
            async for ev in sse(served.port, headers={**AUTH, "Last-Event-ID": "999999999"}):
                got.append(ev)
                if len(got) == 1:
                    assert (await call(served.port, "POST", "/tasks", {"errands": [FREE[4]]},
                                       AUTH)).status == 201
                else:
                    break
        return got, last["last_event"]

    (reset, first), last = asyncio.run(main())
    assert (reset.event, reset.data) == ("reset", {"first": last + 1})
    assert first.event == "task" and first.id == last + 1 and first.data["state"] == "queued"
