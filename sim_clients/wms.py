"""A simulated warehouse management system (WMS): feeds a lifelong gateway through its task API.

:class:`Wms` hands the gateway the tasks of a list, in order (cycled when it runs out), over
HTTP as a real WMS would: ``POST /tasks`` with the operator's token, an ``Idempotency-Key`` per
batch (a POST that fails on the way is retried under the same key, so it never creates a task
twice), and ``GET /tasks/events`` (server-sent events) to learn which tasks ended. It keeps
``keep`` of its tasks outstanding (submitted, not finished or cancelled) plus a ``lead`` in
the gateway's backlog, topping up in batches each time tasks end. With ``keep`` the gateway's
``reveal`` (LoRR's ``numTasksReveal`` x team size), the gateway reveals exactly the LoRR
Start-Kit's task stream (the backlog is first in, first out among equal priorities) while the
lead absorbs the WMS's reaction time.

The HTTP client is deliberately small (one request per connection, as the gateway answers with
``Connection: close``); every POST's round trip is recorded in :attr:`WmsStats.post_ms`.
"""

from __future__ import annotations

import asyncio
import json
import time
from collections.abc import AsyncIterator, Sequence
from dataclasses import dataclass, field
from typing import Any

Cell = tuple[int, int]


class WmsError(RuntimeError):
    """The gateway refused a request (the message has its status and error line)."""


class ShiftEnded(WmsError):
    """The gateway's shift has ended: it takes no more tasks (409), so the WMS stops."""


@dataclass
class WmsStats:
    """What the WMS did: submissions, ends seen, POST round trips, the tightest lead."""

    submitted: int = 0
    ended: int = 0
    posts: int = 0
    retries: int = 0
    post_ms: list[float] = field(default_factory=list)
    """Round trip of every successful ``POST /tasks`` (ms, wall clock)."""
    min_lead: int | None = None
    """The fewest outstanding tasks beyond ``keep`` seen when tasks ended, before the top-up
    (negative: the gateway had fewer than ``keep`` tasks for a moment)."""


async def http(port: int, method: str, path: str, token: str, body: Any = None,
               headers: dict[str, str] | None = None, host: str = "127.0.0.1"
               ) -> tuple[int, Any]:
    """One request on its own connection: ``(status, JSON body)``."""
    payload = b"" if body is None else json.dumps(body, separators=(",", ":")).encode()
    lines = [f"{method} {path} HTTP/1.1", f"Host: {host}:{port}",
             f"Authorization: Bearer {token}", f"Content-Length: {len(payload)}",
             *(f"{k}: {v}" for k, v in (headers or {}).items())]
    if body is not None:
        lines.append("Content-Type: application/json")
    reader, writer = await asyncio.open_connection(host, port)
    try:
        writer.write("\r\n".join(lines).encode() + b"\r\n\r\n" + payload)
        await writer.drain()
        status_line = await reader.readline()
        length = None
        while (line := await reader.readline()) not in (b"\r\n", b""):
            name, _, value = line.decode("latin-1").partition(":")
            if name.strip().lower() == "content-length":
                length = int(value)
        content = await (reader.readexactly(length) if length is not None else reader.read())
    finally:
        writer.close()
    return int(status_line.split()[1]), json.loads(content) if content else None


async def events(port: int, token: str, after: int = 0, host: str = "127.0.0.1"
                 ) -> AsyncIterator[tuple[str, Any]]:
    """``(event, data)`` of the task event stream after event ``after``, until it closes."""
    reader, writer = await asyncio.open_connection(host, port)
    try:
        writer.write(f"GET /tasks/events?after={after} HTTP/1.1\r\nHost: {host}:{port}\r\n"
                     f"Authorization: Bearer {token}\r\n\r\n".encode())
        await writer.drain()
        status = int((await reader.readline()).split()[1])
        while (await reader.readline()) not in (b"\r\n", b""):
            pass
        if status != 200:
            raise WmsError(f"GET /tasks/events: {status}")
        kind, data = "message", ""
        while line := await reader.readline():
            text = line.decode().rstrip("\r\n")
            if text.startswith("event:"):
                kind = text[6:].strip()
            elif text.startswith("data:"):
                data = text[5:].strip()
            elif not text and data:
                yield kind, json.loads(data)
                kind, data = "message", ""
    finally:
        writer.close()


class Wms:
    """Keeps ``keep + lead`` of ``tasks`` (errand cells) outstanding in the gateway on ``port``
    (see the module doc); :meth:`run` until cancelled."""

    def __init__(self, port: int, token: str, tasks: Sequence[Sequence[Cell]], keep: int,
                 lead: int, batch: int = 200, host: str = "127.0.0.1") -> None:
        if not tasks or keep < 1 or lead < 0 or batch < 1:
            raise ValueError("a WMS needs tasks, keep >= 1, lead >= 0 and batch >= 1")
        self.port, self.token, self.host = port, token, host
        self.tasks = tasks
        self.keep, self.lead, self.batch = keep, lead, batch
        self.stats = WmsStats()
        self._mine: set[int] = set()  # ids of its tasks not ended (events are read only
        # between POSTs, so a task's end is never seen before its POST's answer)
        self._posts = 0

    @property
    def outstanding(self) -> int:
        """Tasks submitted and not ended."""
        return self.stats.submitted - self.stats.ended

    async def fill(self) -> None:
        """Submit the next tasks until ``keep + lead`` are outstanding."""
        while (missing := self.keep + self.lead - self.outstanding) > 0:
            await self._post(min(missing, self.batch))

    async def _post(self, count: int) -> None:
        first = self.stats.submitted
        body = {"tasks": [{"errands": [list(c) for c in self.tasks[(first + i) % len(
            self.tasks)]]} for i in range(count)]}
        key = f"wms-{id(self):x}-{self._posts}"
        self._posts += 1
        for attempt in range(3):
            t0 = time.perf_counter()
            try:
                status, answer = await http(self.port, "POST", "/tasks", self.token, body,
                                            {"Idempotency-Key": key}, self.host)
            except (OSError, asyncio.IncompleteReadError, ValueError, IndexError) as exc:
                if attempt == 2:
                    raise WmsError(f"POST /tasks failed 3 times: {exc!r}") from None
                self.stats.retries += 1
                continue
            if status == 409 and str(answer.get("error")).startswith("the shift has ended"):
                raise ShiftEnded(f"POST /tasks: {status} {answer}")
            if status not in (200, 201):
                raise WmsError(f"POST /tasks: {status} {answer}")
            self.stats.post_ms.append((time.perf_counter() - t0) * 1000.0)
            break
        self.stats.posts += 1
        ids = {int(t["id"]) for t in answer["tasks"]}
        self.stats.submitted += len(ids)
        self._mine |= ids

    async def run(self) -> None:
        """Fill, then follow the event stream: each time tasks end, top up. Returns when the
        gateway is gone (its stream closed and a new one is refused) or its shift ended."""
        after = 0
        while True:
            try:
                await self.fill()
                async for kind, data in events(self.port, self.token, after, self.host):
                    if kind == "reset":
                        raise WmsError("the task event stream dropped events (the WMS fell "
                                       "behind)")
                    if kind != "task":
                        continue
                    after = int(data["seq"])
                    if data["state"] in ("finished", "cancelled") and data["task"] in self._mine:
                        self._mine.discard(data["task"])
                        self.stats.ended += 1
                        lead = self.outstanding - self.keep
                        self.stats.min_lead = lead if self.stats.min_lead is None \
                            else min(self.stats.min_lead, lead)
                        await self.fill()
            except (OSError, ShiftEnded):
                return
