"""The records of the owner <-> worker channel: tuples of plain values (ints, floats, strings,
None), one per event or command, its code first; a batch of them is one
:func:`~gateway.server.workers.channel.frame`.

A robot's reports and ``state`` (almost all the traffic) travel as flat records of the fields
the owner uses, an action as its JSON body: neither side builds, pickles or unpickles a
pydantic model for them (a pickled model costs about 1.4 us to write and as much to read; a
record about 0.07 us each way). The rare rest (``hello``, ``refused``, an intruder report,
an operator-bound message) is pickled inside its record.

Events, worker -> owner (``sid``: the connection's session in that worker; ``received``:
``time.perf_counter()`` at its arrival there):

- ``(OPENED, sid, role, robot_id)``: a connection was authenticated;
- ``(REPORT, sid, received, kind, msg_id, action_id, x, y, heading)``: an ``ack`` or an action
  report of :data:`REPORT_TYPES` (``x`` < 0: no pose). The records are the same whatever the
  connection's protocol version; a v3 robot sends no ``ack``, so its actions take one
  ``REPORT`` less each;
- ``(STATE, sid, received, x, y, heading)``: a robot's ``state`` (only its pose is used);
- ``(MESSAGE, sid, received, pickled message)``: any other admitted message;
- ``(CLOSED, sid)``: the connection ended;
- ``(PONG, errors)``: the answer to a ``PING``, with the protocol errors the worker replied
  since its last ``PONG`` (``{code: count}``).

Commands, owner -> worker, applied in order (ignored for a session that ended):

- ``(ACTION, sid, body)``: an ``action`` (``body``: :func:`~protocol.codec.action_body`);
- ``(SEND, sid, pickled (kind, fields))``: any other message;
- ``(ERROR, sid, code, ref, detail)``: an ``error`` reply, counted against the budget there;
- ``(CLOSE, sid, code, reason)``: flush and close;
- ``(VERSION, sid, v)``: the protocol version to answer in;
- ``(PING,)``: answer with a ``PONG``;
- ``(COLLECTOR, paused)``: no cyclic collection in the worker while a one-shot run goes on
  (``True``), or its rare passes again once it is complete (``False``)
  (:mod:`~gateway.server.gc_tuning`).
"""

from __future__ import annotations

import functools
import pickle
from typing import Any

from protocol import (
    Ack,
    AnyMessage,
    Blocked,
    Cancelled,
    Finished,
    Started,
    State,
    Unblocked,
)
from protocol.messages import Pose

Op = tuple[Any, ...]
"""One record: its code first."""

OPENED, REPORT, STATE, MESSAGE, CLOSED, PONG = range(6)
ACTION, SEND, ERROR, CLOSE, VERSION, PING, COLLECTOR = range(7)

REPORT_TYPES: dict[type[AnyMessage], str] = {
    Ack: "ack", Started: "started", Finished: "finished", Blocked: "blocked",
    Unblocked: "unblocked", Cancelled: "cancelled"}
"""The messages sent as a ``REPORT`` record, and their type: their fields are the envelope's,
``action_id`` and (all but ``ack``) ``pose``; the owner uses none of the envelope's but
``msg_id`` (``v`` is the connection's, fixed by its ``hello``)."""


def event(sid: int, message: AnyMessage, received: float) -> Op:
    """The record of an admitted ``message`` on the worker's session ``sid``."""
    kind = REPORT_TYPES.get(type(message))
    if kind is not None:
        pose: Pose | None = getattr(message, "pose", None)
        if pose is None:
            return (REPORT, sid, received, kind, message.msg_id,
                    message.action_id, -1, -1, None)  # type: ignore[union-attr]
        return (REPORT, sid, received, kind, message.msg_id, message.action_id,  # type: ignore[union-attr]
                pose.cell[0], pose.cell[1], pose.heading)
    if type(message) is State:
        pose = message.pose
        if pose is None:
            return (STATE, sid, received, -1, -1, None)
        return (STATE, sid, received, pose.cell[0], pose.cell[1], pose.heading)
    return (MESSAGE, sid, received, pickle.dumps(message, protocol=pickle.HIGHEST_PROTOCOL))


@functools.lru_cache(maxsize=1 << 16)
def pose(x: int, y: int, heading: str | None) -> Pose | None:
    """The pose of a record's ``x, y, heading`` (None if ``x`` < 0); one model per pose
    (poses are immutable), not one per report."""
    return None if x < 0 else Pose.model_construct(cell=(x, y), heading=heading)


def message(record: Op) -> AnyMessage:
    """The message of a ``MESSAGE`` record."""
    loaded: AnyMessage = pickle.loads(record[3])
    return loaded
