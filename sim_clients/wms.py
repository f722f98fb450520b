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

The HTTP client is :mod:`sim_clients.http_client` (one request per connection); every POST's
round trip is recorded in :attr:`WmsStats.post_ms`.
"""

from __future__ import annotations

import asyncio
import json
import time
from collections.abc import AsyncIterator, Sequence
from dataclasses import dataclass, field
from typing import Any

import h11

from sim_clients.http_client import events as sse_events
from sim_clients.http_client import exchange, request

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
    sent = {"Authorization": f"Bearer {token}", "Connection": "close", **(headers or {})}
    if body is not None:
        sent["Content-Type"] = "application/json"
    status, _, content = await request(port, method, path, sent, payload, host)
    return status, json.loads(content) if content else None


async def events(port: int, token: str, after: int = 0, host: str = "127.0.0.1"
                 ) -> AsyncIterator[tuple[str, Any]]:
    """``(event, data)`` of the task event stream after event ``after``, until it closes."""
    parts = exchange(port, "GET", f"/tasks/events?after={after}",
                     {"Authorization": f"Bearer {token}"}, b"", host)
    head = await anext(parts)
    assert isinstance(head, h11.Response)
    if head.status_code != 200:
        await parts.aclose()
        raise WmsError(f"GET /tasks/events: {head.status_code}")
    async for kind, _, data in sse_events(parts):
        yield kind, json.loads(data)


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
