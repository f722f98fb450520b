"""What the owner task's queue carries: connection events, validated messages, internal
commands and planner results (produced by connection handlers and helper tasks, consumed by
:class:`gateway.server.engine.Engine` alone)."""

from __future__ import annotations

import asyncio
from collections.abc import Callable
from dataclasses import dataclass
from typing import Literal

from gateway.planning.plan import Plan
from gateway.server.planner import Problem
from gateway.server.wire.session import Session
from protocol import AnyMessage, ErrorCode, OperatorCommand
from protocol.messages import Pose


@dataclass
class Inbound:
    """A validated message from a session (``received`` = perf_counter at arrival).

    ``at_ms`` is the plan time of its arrival: a robot's report is applied at that time, not
    when the owner task gets to it, so a burst of reports does not delay the later ones.
    """

    session: Session
    message: AnyMessage
    received: float
    at_ms: float | None = None


RobotReport = tuple[Session, str, str, str, Pose | None, float]
"""A robot's ``ack``, action report or ``state`` that a worker process admitted, as the
fields the owner uses (no message model is built for it:
:mod:`~gateway.server.workers.records`): ``(session, kind, action_id, msg_id, pose,
received)``; ``kind`` is the message's type ("state": no ``action_id`` or ``msg_id``),
``received`` as in :class:`Inbound`. A plain tuple: nothing to construct per report."""


@dataclass(slots=True)
class RobotReports:
    """The robot reports of one frame from a worker process, in order, arrived at plan time
    ``at_ms`` (as in :class:`Inbound`): one queue item for them all."""

    reports: list[RobotReport]
    at_ms: float


@dataclass
class Connected:
    """A session was opened."""

    session: Session


@dataclass
class Disconnected:
    """A session ended."""

    session: Session


@dataclass
class InternalCommand:
    """An operator command from inside the process (demo, tests); answered on ``reply``."""

    message: OperatorCommand
    reply: asyncio.Future[tuple[ErrorCode | None, str]]


@dataclass
class SolverDone:
    """The planner finished: ``result`` is a plan or the exception it raised."""

    purpose: Literal["load", "replan", "shadow"]
    result: Plan | Exception
    problem: Problem | None
    reply: Session | asyncio.Future[tuple[ErrorCode | None, str]] | None
    ref: str | None
    wall_ms: float


@dataclass
class OwnerCall:
    """Run ``fn`` in the owner task (a helper task hands back a result, e.g. a lifelong plan
    window, or an API request changes state only the owner task may touch)."""

    fn: Callable[[], None]


Item = Inbound | RobotReports | Connected | Disconnected | InternalCommand | SolverDone | OwnerCall
Reply = Session | asyncio.Future[tuple[ErrorCode | None, str]] | None
