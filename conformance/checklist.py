"""A named checklist: checks registered in order, each citing a rule of docs/protocol.md, run
one after the other with a time limit each; a failure never stops the list."""

from __future__ import annotations

import asyncio
from collections.abc import Awaitable, Callable
from dataclasses import dataclass
from typing import Generic, Protocol, TypeVar

from websockets.exceptions import ConnectionClosed, InvalidHandshake

from conformance.report import CheckFailed, CheckResult
from conformance.wire import Breaches

C = TypeVar("C")


@dataclass(frozen=True)
class Check(Generic[C]):
    """One check: ``run(context)`` raises :class:`CheckFailed` if the rule is broken."""

    name: str
    rule: str
    required: bool
    run: Callable[[C], Awaitable[None]]
    doc: str


class Checklist(Generic[C]):
    """Checks in the order they run (see :meth:`check`)."""

    def __init__(self, time_limit_s: float = 30.0) -> None:
        self.checks: list[Check[C]] = []
        self.time_limit_s = time_limit_s

    def add(self, name: str, rule: str, run: Callable[[C], Awaitable[None]], doc: str, *,
            required: bool = True) -> None:
        """Register ``run`` as check ``name`` of rule ``rule``; ``doc`` says what it checks
        (markdown; the reports show it with single backquotes)."""
        if any(c.name == name for c in self.checks):
            raise ValueError(f"check {name!r} is registered twice")
        self.checks.append(Check(name, rule, required, run,
                                 " ".join(doc.split()).replace("``", "`")))

    def check(self, name: str, rule: str, *, required: bool = True
              ) -> Callable[[Callable[[C], Awaitable[None]]], Callable[[C], Awaitable[None]]]:
        """Register the decorated coroutine function as check ``name`` of rule ``rule`` (its
        docstring says what it checks)."""

        def register(fn: Callable[[C], Awaitable[None]]) -> Callable[[C], Awaitable[None]]:
            self.add(name, rule, fn, fn.__doc__ or "", required=required)
            return fn

        return register

    async def run(self, context: C, *, only: set[str] | None = None,
                  progress: Callable[[CheckResult], None] | None = None) -> list[CheckResult]:
        """Run every check (or those named in ``only``); one result each, in order."""
        results: list[CheckResult] = []
        for c in self.checks:
            if only is not None and c.name not in only:
                continue
            passed, detail = await self._one(c, context)
            result = CheckResult(c.name, c.rule, c.required, passed, detail)
            results.append(result)
            if progress is not None:
                progress(result)
        return results

    async def _one(self, c: Check[C], context: C) -> tuple[bool, str]:
        try:
            async with asyncio.timeout(self.time_limit_s):
                await c.run(context)
        except CheckFailed as exc:
            return False, str(exc)
        except TimeoutError:
            return False, f"no verdict within {self.time_limit_s:g} s"
        except ConnectionClosed as exc:
            return False, f"connection closed unexpectedly ({exc})"
        except (OSError, InvalidHandshake) as exc:
            return False, f"connection failed: {exc}"
        return True, c.doc


class Watched(Protocol):
    """A checklist's context that records what the other side broke on every connection."""

    @property
    def breaches(self) -> Breaches:
        """The envelope rules the other side broke so far."""
        ...


W = TypeVar("W", bound=Watched)

_ENVELOPE = [
    ("messages-valid", "MSG-1", "Every message the {side} sent decoded under the strict schema."),
    ("seq-increments", "MSG-2",
     "The {side}'s ``seq`` starts at 0 and grows by 1 on every connection."),
    ("msg-ids-unique", "MSG-3", "The {side} never reused a ``msg_id`` on a connection."),
    ("text-frames", "WS-1", "The {side} sent text frames only."),
]


def add_envelope_checks(checklist: Checklist[W], side: str) -> None:
    """Register the passive checks of the envelope rules, ``<side>-<what>``: verdicts on
    everything ``side`` ("gateway" or "robot") sent during the checks before them."""
    for what, rule, doc in _ENVELOPE:

        async def verdict(context: W, rule: str = rule) -> None:
            context.breaches.verdict(rule)

        checklist.add(f"{side}-{what}", rule, verdict, doc.format(side=side))
