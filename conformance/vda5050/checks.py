"""The checklist a VDA 5050 vehicle goes through: the checker plays the master control over the
broker and drives the vehicle up to three steps along +x of its map and back (docs/vda5050.md,
"Checking a vehicle"). Each check cites the section of the 2.1.0 text it tests; the checks run
in order and build on each other (a check whose predecessor failed may fail for that reason:
its detail says what it saw)."""

from __future__ import annotations

import asyncio
import contextlib
import os
import signal
from collections import Counter
from typing import Any

from conformance.checklist import Checklist
from conformance.report import CheckFailed, CheckResult, UsageProblem
from conformance.vda5050.schemas import have_schemas, schema_errors
from conformance.vda5050.session import VdaOptions, VdaSession

VDA_CHECKS: Checklist[VdaSession] = Checklist(time_limit_s=90.0)
check = VDA_CHECKS.check

QUIET_S = 2.0
"""How long a vehicle must stay put where it has to."""


def _order_of(v: VdaSession) -> tuple[Any, Any]:
    s = v.state or {}
    return s.get("orderId"), s.get("orderUpdateId")


@check("connection-online", "6.14")
async def _online(v: VdaSession) -> None:
    """The vehicle's ``connection`` topic (retained, QoS 1) says ``ONLINE``."""
    await v.until("an ONLINE connection message",
                  lambda v: (v.connection or {}).get("connectionState") == "ONLINE")


@check("state-request", "6.10")
async def _state(v: VdaSession) -> None:
    """A ``stateRequest`` is answered with a ``state`` of this vehicle and version that has an
    initialised ``agvPosition`` (the checks' nodes are placed relative to it)."""
    v.state = None
    await v.instant("stateRequest")
    await v.until("a state after stateRequest", lambda v: v.state is not None)
    s: dict[str, Any] = v.state or {}
    o = v.options
    if (s.get("manufacturer"), s.get("serialNumber")) != (o.manufacturer, o.serial):
        raise CheckFailed(f"the state names {s.get('manufacturer')}/{s.get('serialNumber')}")
    if s.get("version") != o.version:
        raise CheckFailed(f"the state says version {s.get('version')!r}, not {o.version}")
    v.home = v.position()


@check("factsheet", "6.15", required=False)
async def _factsheet(v: VdaSession) -> None:
    """The vehicle publishes its ``factsheet`` (retained; a 2.1 vehicle also on
    ``factsheetRequest``) listing the actions it supports."""
    if v.factsheet is None and not v.options.version.startswith("2.0."):
        await v.instant("factsheetRequest")
    await v.until("a factsheet", lambda v: v.factsheet is not None, 5.0)
    features = (v.factsheet or {}).get("protocolFeatures", {})
    if not isinstance(features, dict) or not features.get("agvActions"):
        raise CheckFailed("the factsheet lists no protocolFeatures.agvActions")


@check("order-base-horizon", "6.6.1")
async def _base(v: VdaSession) -> None:
    """An order with one released edge and a horizon of two: the vehicle drives to the end of
    the base, stops there and does not enter the horizon; its state lists the horizon's nodes
    as not released."""
    await v.order("fgc-1", 0, [(0, True), (1, True), (2, False), (3, False)])
    await v.until("the vehicle at the end of the base (node fgc-n1)", lambda v: v.at("fgc-n1"))
    await v.holds("the vehicle entered the horizon", lambda v: v.at("fgc-n1"), QUIET_S)
    horizon = [(n.get("nodeId"), n.get("released")) for n in (v.state or {}).get(
        "nodeStates", [])]
    if horizon != [("fgc-n2", False), ("fgc-n3", False)]:
        raise CheckFailed(f"nodeStates {horizon}, expected the horizon fgc-n2, fgc-n3 "
                          "unreleased")


@check("order-update", "6.6.2")
async def _update(v: VdaSession) -> None:
    """An update (``orderUpdateId`` 1) stitched on the decision point releases the next edge:
    the vehicle drives on to its end and its state shows the new ``orderUpdateId``."""
    await v.order("fgc-1", 1, [(1, True), (2, True), (3, False)], first_seq=2)
    await v.until("the vehicle at fgc-n2 under update 1",
                  lambda v: v.at("fgc-n2") and _order_of(v) == ("fgc-1", 1))


@check("update-resent-ignored", "6.6.4")
async def _resent(v: VdaSession) -> None:
    """The same update sent again is ignored: no error, the vehicle stays."""
    await v.order("fgc-1", 1, [(1, True), (2, True), (3, False)], first_seq=2)
    await v.holds("the resent update was not ignored",
                  lambda v: v.at("fgc-n2") and not v.errors_about("orderId", "fgc-1"), QUIET_S)


@check("bad-stitching-rejected", "6.6.4")
async def _bad_stitch(v: VdaSession) -> None:
    """An update whose first node is not the decision point is rejected with an error that
    references the order; the vehicle keeps its order and does not move."""
    await v.order("fgc-1", 2, [(0, True), (1, True)], first_seq=0)
    await v.until("an error referencing orderId fgc-1",
                  lambda v: bool(v.errors_about("orderId", "fgc-1")), 5.0)
    await v.holds("the vehicle took the bad update",
                  lambda v: v.at("fgc-n2") and _order_of(v) == ("fgc-1", 1), QUIET_S)


@check("pause-resume", "6.8")
async def _pause(v: VdaSession) -> None:
    """``startPause``: ``paused`` true and the vehicle does not drive a newly released edge;
    ``stopPause``: it drives on. Both instant actions end FINISHED."""
    pause = await v.instant("startPause")
    await v.until("paused after startPause", lambda v: (v.state or {}).get("paused") is True)
    await v.order("fgc-1", 3, [(2, True), (3, True)], first_seq=4)
    await v.holds("the paused vehicle drove", lambda v: v.at("fgc-n2"), QUIET_S)
    resume = await v.instant("stopPause")
    await v.until("at fgc-n3 after stopPause", lambda v: v.at("fgc-n3"))
    for action_id in (pause, resume):
        if v.action_status(action_id) != "FINISHED":
            raise CheckFailed(f"{action_id}: status {v.action_status(action_id)!r}, "
                              "not FINISHED")


@check("cancel-order", "6.8")
async def _cancel(v: VdaSession) -> None:
    """``cancelOrder`` while an order runs: the vehicle stops (at once or at the next node),
    drops the order's nodes and edges, and reports the cancel FINISHED."""
    await v.order("fgc-2", 0, [(3, True), (2, True), (1, True), (0, True)])
    await v.until("driving the new order",
                  lambda v: _order_of(v)[0] == "fgc-2" and bool((v.state or {}).get("driving")))
    cancel = await v.instant("cancelOrder")
    await v.until("cancelOrder FINISHED with no nodes left", lambda v: (
        v.action_status(cancel) == "FINISHED" and not (v.state or {}).get("nodeStates")
        and not (v.state or {}).get("driving")))
    if v.at("fgc-n0"):
        raise CheckFailed("the vehicle drove the whole cancelled order")


@check("order-after-cancel", "6.6.4")
async def _after_cancel(v: VdaSession) -> None:
    """A new order from the node the vehicle stopped on is accepted and driven (the vehicle
    returns to where the checks began)."""
    last = str((v.state or {}).get("lastNodeId", ""))
    if not last.startswith("fgc-n"):
        raise CheckFailed(f"the vehicle stopped on {last!r}, not on a node of the checks")
    k = int(last.removeprefix("fgc-n"))
    await v.order("fgc-3", 0, [(i, True) for i in range(k, -1, -1)])
    await v.until("back at fgc-n0", lambda v: v.at("fgc-n0") and _order_of(v)[0] == "fgc-3")
    if v.errors_about("orderId", "fgc-3"):
        raise CheckFailed(f"errors about the order: {v.errors_about('orderId', 'fgc-3')}")


@check("cancel-without-order", "6.8", required=False)
async def _cancel_nothing(v: VdaSession) -> None:
    """``cancelOrder`` with no order to cancel FAILS and reports ``noOrderToCancel``."""
    cancel = await v.instant("cancelOrder")
    await v.until("cancelOrder FAILED", lambda v: v.action_status(cancel) == "FAILED", 5.0)
    if not any(e.get("errorType") == "noOrderToCancel"
               for e in (v.state or {}).get("errors", [])):
        raise CheckFailed("no noOrderToCancel error")


@check("unreachable-start-rejected", "6.6.4", required=False)
async def _far(v: VdaSession) -> None:
    """A new order whose first node is far from the vehicle is rejected (an error referencing
    the order, e.g. ``noRouteError``) and not driven."""
    await v.order("fgc-4", 0, [(10, True), (11, True)])
    await v.until("an error referencing orderId fgc-4",
                  lambda v: bool(v.errors_about("orderId", "fgc-4")), 5.0)
    await v.holds("the vehicle drove the unreachable order", lambda v: v.at("fgc-n0"), 1.0)


@check("schema-valid", "6.x")
async def _schemas(v: VdaSession) -> None:
    """Every message the vehicle published validates against the official JSON schema of its
    topic and the configured version (``--schemas DIR``: fleetgate carries no copy)."""
    root, version = v.options.schemas, v.options.version
    if root is None or not have_schemas(root, version):
        raise CheckFailed(f"no schemas of {version} under {root} (give --schemas DIR)")
    bad: Counter[str] = Counter()
    first: list[str] = []
    for name, payload in v.received:
        errors = schema_errors(version, name, payload, root)
        if errors:
            bad[name] += 1
            first = first or [f"{name}: {errors[0]}"]
    if bad:
        raise CheckFailed(f"{sum(bad.values())} of {len(v.received)} messages break the "
                          f"schema ({dict(bad)}); first: {first[0]}")


@check("last-will", "6.14", required=False)
async def _will(v: VdaSession) -> None:
    """Killed (SIGKILL to what ``--command`` started), the vehicle's last will
    ``CONNECTIONBROKEN`` reaches the master through the broker."""
    proc = v.process
    if proc is None:
        raise CheckFailed("needs --command (the checker kills the vehicle it started)")
    with contextlib.suppress(ProcessLookupError):
        os.killpg(proc.pid, signal.SIGKILL)
    await proc.wait()
    await v.until("CONNECTIONBROKEN after the kill", lambda v: (
        v.connection or {}).get("connectionState") == "CONNECTIONBROKEN",
        v.options.will_timeout_s)


async def run_vda_checks(options: VdaOptions, only: set[str] | None = None
                         ) -> list[CheckResult]:
    """Play the master control for the vehicle through the checklist; UsageProblem if the
    broker cannot be reached."""
    session = VdaSession(options)
    ready = asyncio.Event()
    listening = asyncio.create_task(session.run(ready))
    try:
        done, _ = await asyncio.wait({listening, asyncio.ensure_future(ready.wait())},
                                     return_when=asyncio.FIRST_COMPLETED)
        if listening in done:
            listening.result()  # raises UsageProblem
            raise UsageProblem("the MQTT connection closed")
        await session.start_vehicle()
        return await VDA_CHECKS.run(session, only=only)
    finally:
        await session.stop_vehicle()
        listening.cancel()
        with contextlib.suppress(asyncio.CancelledError, UsageProblem):
            await listening
