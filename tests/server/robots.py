"""A minimal robot and operator written against the protocol models (test helpers).

``TestRobot`` executes every action it is sent: ``started``, then (after ``move_s`` on the
loop clock) ``finished``; it honours pause/resume and cancel, and drops duplicate actions.
"""

from __future__ import annotations

import asyncio
import itertools
from collections.abc import Sequence
from typing import Any, Protocol

from websockets.exceptions import ConnectionClosed

from protocol import (
    Ack,
    Action,
    AnyMessage,
    CancelAction,
    Cancelled,
    Error,
    Event,
    Finished,
    Hello,
    Pause,
    Resume,
    Snapshot,
    Started,
    Welcome,
    decode,
    encode,
)


class ClientLink(Protocol):
    """What both a websockets client connection and a MemoryClient offer."""

    async def send(self, message: str) -> None: ...
    async def recv(self) -> str | bytes: ...
    async def close(self, code: int = 1000, reason: str = "") -> None: ...


class Peer:
    """Sends protocol messages with its own msg_id/seq and reads typed replies."""

    def __init__(self, link: ClientLink, name: str) -> None:
        self.link = link
        self.name = name
        self._seq = itertools.count()
        self.inbox: list[AnyMessage] = []

    async def send(self, kind: type[AnyMessage], **fields: Any) -> str:
        """Send a message; returns its msg_id."""
        seq = next(self._seq)
        msg_id = f"{self.name}-{seq}"
        await self.link.send(encode(kind(msg_id=msg_id, seq=seq, **fields)))
        return msg_id

    async def send_raw(self, text: str) -> None:
        """Send arbitrary text."""
        await self.link.send(text)

    async def recv(self) -> AnyMessage:
        """Next message (decoded)."""
        msg = decode(await self.link.recv())
        self.inbox.append(msg)
        return msg

    async def expect(self, kind: type[AnyMessage], timeout: float = 5.0) -> Any:
        """Skip messages until one of ``kind`` arrives."""
        async with asyncio.timeout(timeout):
            while True:
                msg = await self.recv()
                if isinstance(msg, kind):
                    return msg

    async def error_for(self, ref: str | None, timeout: float = 5.0) -> Error:
        """Skip messages until the ``error`` that refers to ``ref``."""
        async with asyncio.timeout(timeout):
            while True:
                msg = await self.recv()
                if isinstance(msg, Error) and msg.ref == ref:
                    return msg


class TestRobot(Peer):
    """A robot that executes whatever it is dispatched."""

    __test__ = False

    def __init__(self, link: ClientLink, robot_id: int, move_s: float = 0.0,
                 ack: bool = True) -> None:
        super().__init__(link, f"r{robot_id}")
        self.robot_id = robot_id
        self.move_s = move_s
        self.ack = ack
        self.seen: set[str] = set()
        self.finished: list[str] = []
        self.resumed = asyncio.Event()
        self.resumed.set()
        self.welcome: Welcome | None = None

    async def hello(self, **fields: Any) -> Welcome:
        """Say hello; returns the welcome."""
        await self.send(Hello, robot_id=self.robot_id, **fields)
        self.welcome = await self.expect(Welcome)
        if self.welcome.paused:
            self.resumed.clear()
        return self.welcome

    async def run(self, backlog: Sequence[Action] = ()) -> None:
        """Execute the welcome's resend list, ``backlog``, then what arrives, until closed."""
        queue: asyncio.Queue[Action] = asyncio.Queue()
        cancelled: set[str] = set()
        for a in [*(self.welcome.resend if self.welcome else []), *backlog]:
            if a.action_id not in self.seen or a in backlog:
                self.seen.add(a.action_id)
                queue.put_nowait(a)
        worker = asyncio.create_task(self._work(queue, cancelled))
        try:
            while True:
                msg = await self.recv()
                if isinstance(msg, Action) and msg.action_id not in self.seen:
                    self.seen.add(msg.action_id)
                    if self.ack:
                        await self.send(Ack, action_id=msg.action_id)
                    queue.put_nowait(msg)
                elif isinstance(msg, CancelAction):
                    cancelled.add(msg.action_id)
                elif isinstance(msg, Pause):
                    self.resumed.clear()
                elif isinstance(msg, Resume):
                    self.resumed.set()
        except ConnectionClosed:
            pass
        finally:
            worker.cancel()

    async def _work(self, queue: asyncio.Queue[Action], cancelled: set[str]) -> None:
        while True:
            action = await queue.get()
            await self.resumed.wait()
            if action.action_id in cancelled:
                await self.send(Cancelled, action_id=action.action_id, pose=action.src)
                continue
            await self.send(Started, action_id=action.action_id, pose=action.src)
            await asyncio.sleep(self.move_s)
            await self.send(Finished, action_id=action.action_id, pose=action.dst)
            self.finished.append(action.action_id)


class TestOperator(Peer):
    """An operator: first message is the snapshot, then events."""

    __test__ = False
    _cursor = 0

    async def snapshot(self) -> Snapshot:
        """The next snapshot."""
        snap: Snapshot = await self.expect(Snapshot)
        return snap

    async def event(self, kind: str, timeout: float = 10.0) -> Event:
        """The next event of ``kind`` after the last one returned (also among messages that
        other helpers already read into the inbox)."""
        cursor = self._cursor
        async with asyncio.timeout(timeout):
            while True:
                for i in range(cursor, len(self.inbox)):
                    msg = self.inbox[i]
                    if isinstance(msg, Event) and msg.event == kind:
                        self._cursor = i + 1
                        return msg
                cursor = len(self.inbox)
                await self.recv()
