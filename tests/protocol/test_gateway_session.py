"""The gateway's side of the protocol (protocol.gateway_session), by hand and wired to the
robot's side (protocol.robot_session) over a lossy link.

The property test runs both sans-I/O sessions against each other, in protocol v2 (an ``ack``
per action) and v3 (no ``ack``: the first report acknowledges): the gateway dispatches a
robot's actions in index order and cancels queued ones at random, messages in flight are
delivered one at a time or lost with the link, the robot reconnects, duplicates are injected,
the robot's body refuses an action when it is due (with the actions queued behind it) and the
gateway dispatches what it took back again (as a lifelong shift does, with the same ids).
Oracle: at the end every dispatched action ended exactly once (finished or cancelled, never
both; a refusal is not an end), nothing is held, and the robot executed exactly the finished
ones, once each and in index order.
"""

from __future__ import annotations

from collections import deque
from typing import Any, cast

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from protocol import (
    Action,
    AnyMessage,
    Cancelled,
    ErrorCode,
    Finished,
    Hello,
    Pose,
    Welcome,
)
from protocol.gateway_session import (
    APPLIED_KEEP,
    GatewaySession,
    Refuse,
    Report,
    ToRobot,
    hello_refusal,
)
from protocol.messages import ProtocolVersion
from protocol.robot_session import Abort, RobotSession, Send

_n = iter(range(10**9))


def fields(i: int) -> dict[str, Any]:
    return {"action_id": f"0.0.{i}", "sequence": i, "src": Pose(cell=(i, 0)),
            "dst": Pose(cell=(i + 1, 0)), "duration_ms": 1000.0}


def hello(**kw: Any) -> Hello:
    n = next(_n)
    return Hello(msg_id=f"h{n}", seq=0, robot_id=0, **kw)


def welcome_of(effects: list[Any]) -> Welcome:
    (w,) = [e.fields for e in effects if isinstance(e, ToRobot) and e.kind is Welcome]
    return Welcome(msg_id="w", seq=0, **w)


def accept_all(gs: GatewaySession) -> list[Any]:
    """Drain, applying every report (an executor that takes everything)."""
    out = []
    while effects := gs.drain():
        for e in effects:
            if isinstance(e, Report):
                gs.accepted(e)
            out.append(e)
    return out


def test_hello_catches_up_and_the_welcome_resends_only_what_the_robot_lacks() -> None:
    gs = GatewaySession(0)
    link = object()
    gs.hello(hello(), 0.0)
    gs.welcome(link, version=2, start=None, plan=0, state_period_ms=100.0, paused=False)
    accept_all(gs)
    for i in range(3):
        gs.dispatch(fields(i))
    assert [type(e.kind) for e in gs.drain()] == [type(Action)] * 3
    gs.ack("0.0.0", "m1", link)
    gs.ack("0.0.1", "m2", link)
    gs.report("started", "0.0.0", "m3", link, 5.0)
    assert [(r.kind, r.action_id) for r in accept_all(gs)] == [("started", "0.0.0")]
    assert gs.disconnected(link) and not gs.connected
    # the finish of 0.0.0 and the ack of 0.0.2 were lost; the robot holds 0.0.1 and 0.0.2
    gs.hello(hello(finished=["0.0.0"], acked=["0.0.1", "0.0.2"]), 9.0)
    reports = [e for e in accept_all(gs) if isinstance(e, Report)]
    assert [(r.kind, r.action_id, r.t_ms, r.ref) for r in reports] == [
        ("finished", "0.0.0", 9.0, None)]
    gs.welcome(object(), version=2, start=None, plan=0, state_period_ms=100.0, paused=False)
    assert welcome_of(gs.drain()).resend == []
    assert gs.applied == {"0.0.0": "finished"} and gs.next_index == 1
    assert all(h.acked for h in gs.held.values())


def test_a_lost_action_is_resent_and_owed_cancels_are_settled() -> None:
    gs = GatewaySession(0)
    link = object()
    gs.hello(hello(), 0.0)
    gs.welcome(link, version=2, start=None, plan=0, state_period_ms=100.0, paused=False)
    for i in range(3):
        gs.dispatch(fields(i))
        gs.ack(f"0.0.{i}", f"a{i}", link)
    gs.drain()
    gs.disconnected(link)
    gs.cancel("0.0.1")  # a replan while it is away
    gs.cancel("0.0.2")
    assert gs.drain() == []  # offline: nothing sent
    # it restarted: holds 0.0.2 only (it lost 0.0.0 and 0.0.1 although it acked them)
    gs.hello(hello(acked=["0.0.2"]), 3.0)
    reports = [(e.kind, e.action_id) for e in accept_all(gs) if isinstance(e, Report)]
    assert reports == [("cancelled", "0.0.1")]  # it no longer holds it: nobody else confirms
    link2 = object()
    gs.welcome(link2, version=2, start=None, plan=0, state_period_ms=100.0, paused=False)
    effects = gs.drain()
    assert [a.action_id for a in welcome_of(effects).resend] == ["0.0.0"]
    assert [e.fields for e in effects if isinstance(e, ToRobot) and e.kind.__name__ ==
            "CancelAction"] == [{"action_id": "0.0.2"}]  # it holds it: it confirms itself


def test_refusals_duplicates_and_unknown_actions() -> None:
    gs = GatewaySession(0)
    link = object()
    gs.report("finished", "0.0.0", "early", link, 0.0)
    assert gs.drain() == [Refuse(ErrorCode.BAD_STATE, "early", "say hello first")]
    gs.hello(hello(), 0.0)
    gs.welcome(link, version=2, start=None, plan=0, state_period_ms=100.0, paused=False)
    gs.drain()
    gs.dispatch(fields(0))
    gs.drain()
    gs.ack("0.0.7", "x", link)
    gs.report("started", "0.0.7", "y", link, 1.0)
    assert [(e.code, e.ref) for e in gs.drain() if isinstance(e, Refuse)] == [
        (ErrorCode.UNKNOWN_ACTION, "x"), (ErrorCode.UNKNOWN_ACTION, "y")]
    gs.report("started", "0.0.0", "s1", link, 1.0)
    (r,) = gs.drain()
    assert isinstance(r, Report)
    gs.rejected(r, "out of order")  # the executor refused it: nothing changed
    assert gs.held["0.0.0"].phase == "dispatched"
    assert gs.drain() == [Refuse(ErrorCode.REJECTED, "s1", "out of order")]
    gs.report("started", "0.0.0", "s2", link, 1.0)
    accept_all(gs)
    gs.report("started", "0.0.0", "s3", link, 1.5)
    gs.report("finished", "0.0.0", "f1", link, 2.0)
    accept_all(gs)
    gs.report("finished", "0.0.0", "f2", link, 2.5)
    codes = [(e.code, e.ref) for e in gs.drain() if isinstance(e, Refuse)]
    assert codes == [(ErrorCode.DUPLICATE, "f2")]
    assert gs.applied == {"0.0.0": "finished"}


def test_a_long_shift_keeps_only_the_latest_applied_actions() -> None:
    """A lifelong shift never starts a new plan: ``applied`` stays bounded, a reconnecting
    robot's catch-up and a late repeat of a recent report are still recognised, and a repeat
    of a long-forgotten action is refused without changing anything."""
    gs = GatewaySession(0)
    link = object()
    gs.hello(hello(), 0.0)
    gs.welcome(link, version=2, start=None, plan=0, state_period_ms=100.0, paused=False)
    n = 3 * APPLIED_KEEP
    for i in range(n):
        gs.dispatch(fields(i))
        gs.report("started", f"0.0.{i}", f"s{i}", link, float(i))
        gs.report("finished", f"0.0.{i}", f"f{i}", link, i + 0.5)
        accept_all(gs)
    assert len(gs.applied) == APPLIED_KEEP and gs.next_index == n
    assert next(iter(gs.applied)) == f"0.0.{n - APPLIED_KEEP}"
    gs.report("finished", f"0.0.{n - 1}", "late", link, n + 1.0)
    gs.report("finished", "0.0.0", "ancient", link, n + 1.0)
    assert [(e.code, e.ref) for e in gs.drain()] == [
        (ErrorCode.DUPLICATE, "late"), (ErrorCode.UNKNOWN_ACTION, "ancient")]
    # the robot comes back listing the last 256 finishes (a hello's limit): nothing is applied
    # again, nothing is disowned
    gs.disconnected(link)
    gs.dispatch(fields(n))
    recent = [f"0.0.{i}" for i in range(n - 256, n)]
    gs.hello(hello(finished=recent, acked=[f"0.0.{n}"]), n + 2.0)
    assert accept_all(gs) == [] and gs.disowned == set()
    assert len(gs.applied) == APPLIED_KEEP and gs.next_index == n


# ---------------------------------------------------------------------------- property test
OPS = st.lists(st.sampled_from(
    ["dispatch", "dispatch", "to_robot", "to_robot", "to_gateway", "to_gateway", "step",
     "step", "duplicate", "cancel", "cut", "reconnect", "refuse", "redispatch"]), max_size=80)


class Wire:
    """Both sessions (speaking protocol ``version``), the link between them and the robot's
    body."""

    def __init__(self, n: int, version: ProtocolVersion = 3) -> None:
        self.version: ProtocolVersion = version
        self.robot = RobotSession(0, version=version)
        self.gw = GatewaySession(0)
        self.n, self.next, self.plan, self.refusals = n, 0, 0, 0
        self.refused_on_link = False
        self.link: object | None = None
        self.to_robot: deque[AnyMessage] = deque()
        self.to_gw: deque[AnyMessage] = deque()
        self.body: str | None = None
        self.executed: list[int] = []
        self.applied: list[tuple[str, str]] = []

    def pump(self) -> None:
        for e in self.robot.drain():
            if isinstance(e, Send) and self.link is not None:
                self.to_gw.append(e.message)
            elif isinstance(e, Abort):
                assert self.body == e.action_id
                self.body = None
        while effects := self.gw.drain():
            for g in effects:
                if isinstance(g, ToRobot) and self.link is not None:
                    n = next(_n)
                    self.to_robot.append(g.kind(msg_id=f"g{n}", seq=n, **g.fields))
                elif isinstance(g, Report):
                    self.gw.accepted(g)
                    if g.kind in ("finished", "cancelled", "refused"):
                        self.applied.append((g.action_id, g.kind))
                elif isinstance(g, Refuse):
                    assert g.code is ErrorCode.DUPLICATE, g

    def connect(self) -> None:
        self.refused_on_link = False
        self.to_robot.clear()
        self.to_gw.clear()
        self.link = object()
        self.robot.connected()
        (msg,) = [e.message for e in self.robot.drain() if isinstance(e, Send)]
        assert isinstance(msg, Hello)
        self.gw.hello(msg, 0.0)
        self.pump()
        self.gw.welcome(self.link, version=self.version, start=None, plan=0,
                        state_period_ms=1e3, paused=False)
        self.pump()

    def cut(self) -> None:
        self.gw.disconnected(self.link)
        self.robot.disconnected()
        self.link = None
        self.to_robot.clear()
        self.to_gw.clear()

    def op(self, op: str) -> None:
        if op == "dispatch" and self.next < self.n and "refused" not in self.gw.applied.values():
            # waits on one cell: this model's gateway goes on with the plan after a cancel,
            # which only actions that start where the robot stands allow (else: refused);
            # after a refusal it sends nothing new until what it took back is sent again (in
            # index order, as a lifelong shift's next planning call does)
            self.gw.dispatch(self.wait(self.plan, self.next))
            self.next += 1
        elif op == "to_robot" and self.to_robot:
            self.robot.receive(self.to_robot.popleft())
        elif op == "to_gateway" and self.to_gw:
            msg = self.to_gw.popleft()
            kind = msg.type
            assert msg.v == self.version
            if kind == "ack":
                assert self.version < 3, "a v3 robot sends no ack"
                self.gw.ack(msg.action_id, msg.msg_id, self.link)  # type: ignore[union-attr]
            elif kind in ("started", "finished", "blocked", "unblocked", "cancelled",
                          "refused"):
                self.gw.report(kind, msg.action_id, msg.msg_id,  # type: ignore[union-attr]
                               self.link, 0.0, reason="test")
        elif op == "duplicate" and self.link is not None and not self.refused_on_link:
            # a resend of a held action (the gateway never sends one it is cancelling: a later
            # copy would revive it; nor, on the live link, one the robot may have refused: a
            # gateway resends only in a welcome, and the robot takes a copy of the action it
            # refused for its dispatch again)
            held = [h for h in self.gw.held.values() if not h.cancel]
            if held:
                n = next(_n)
                self.to_robot.append(Action(msg_id=f"d{n}", seq=n, **held[-1].fields))
        elif op == "cancel" and not self.refusals:  # a replan: every queued action of the
            # robot at once; the rest of the actions are of the next plan. (A run has either
            # replans or refusals: a replan waits for every cancel to be confirmed, which
            # this model's gateway does not.)
            for aid in reversed([a for a, h in self.gw.held.items() if h.phase != "running"]):
                self.gw.cancel(aid)
            self.plan += 1
        elif op == "step":
            self.step()
        elif (op == "refuse" and self.plan == 0 and self.body is None
              and not any(m.msg_id.startswith("d") for m in self.to_robot)  # (as above)
              and self.robot.take() is not None):
            self.robot.refuse_current("cannot_execute", "not now")  # and its queue
            self.refusals += 1
            self.refused_on_link = True
        elif op == "redispatch":  # what a refusal took back, again, in index order
            for aid in sorted((a for a, k in self.gw.applied.items() if k == "refused"),
                              key=lambda a: int(a.split(".")[2])):
                plan, _, i = (int(x) for x in aid.split("."))
                self.gw.dispatch(self.wait(plan, i))
        elif op == "cut" and self.link is not None:
            self.cut()
        elif op == "reconnect" and self.link is None:
            self.connect()
        self.pump()
        # the gateway never takes back (as refused) an action the robot holds: a late refusal
        # of an earlier dispatch is not taken for the new one
        holds = {a.action_id for a in self.robot.queue} | {self.robot.current} - {None}
        assert not holds & {a for a, k in self.gw.applied.items() if k == "refused"}, holds

    @staticmethod
    def wait(plan: int, i: int) -> dict[str, Any]:
        """Action ``i`` of ``plan``: a wait on one cell (this model's gateway goes on with the
        plan after a cancel, which only actions that start where the robot stands allow)."""
        return {"action_id": f"{plan}.0.{i}", "sequence": i, "src": Pose(cell=(0, 0)),
                "dst": Pose(cell=(0, 0)), "duration_ms": 1000.0}

    def step(self) -> None:
        if self.body is not None:
            self.robot.report("finished", self.body)
            self.executed.append(int(self.body.split(".")[2]))
            self.body = None
        elif (a := self.robot.take()) is not None:
            self.body = a.action_id
            self.robot.report("started", a.action_id)


REFUSAL_OPS = st.lists(st.sampled_from(
    ["dispatch", "to_robot", "to_gateway", "cut", "reconnect", "refuse", "redispatch"]),
    max_size=30)
"""Fewer kinds, so that refusals of held actions, reconnects and dispatches again meet often."""


@settings(max_examples=200, deadline=None)
@given(OPS, st.sampled_from([2, 3]))
def test_random_interleavings_never_lose_or_double_an_action(ops: list[str], version: int
                                                             ) -> None:
    run_wire(ops, version)


@settings(max_examples=1000, deadline=None)
@given(REFUSAL_OPS, st.sampled_from([2, 3]))
def test_random_refusals_and_reconnects_never_lose_or_double_an_action(ops: list[str],
                                                                       version: int) -> None:
    run_wire(ops, version)


def run_wire(ops: list[str], version: int) -> None:
    """Run ``ops`` on a :class:`Wire` of 8 actions, settle, and check the oracle."""
    w = Wire(8, cast(ProtocolVersion, version))
    w.connect()
    for op in ops:
        w.op(op)
    settle_and_check(w)


@settings(max_examples=100, deadline=None)
@given(st.integers(2, 4), st.booleans(), st.integers(0, 5), st.sampled_from([2, 3]))
def test_a_refusal_of_held_actions_and_their_dispatch_again_in_any_order(
        held: int, cut: bool, early: int, version: int) -> None:
    # the robot holds ``held`` actions (said in a hello after a cut link, or acknowledged),
    # its body refuses the first one when it is due (and the robot drops the rest); the
    # gateway takes them back on the first refusal and dispatches them again after ``early``
    # more of the robot's messages: the later refusals are about the old dispatch
    w = Wire(held, cast(ProtocolVersion, version))
    w.connect()
    for op in ["dispatch"] * held + ["to_robot"] * (held + 1):  # the welcome, then the actions
        w.op(op)
    if cut:
        for op in ["cut", "reconnect", "to_robot"]:
            w.op(op)
    w.op("refuse")
    while w.to_gw and w.to_gw[0].type != "refused":
        w.op("to_gateway")
    w.op("to_gateway")
    for _ in range(early):
        w.op("to_gateway")
    w.op("redispatch")
    settle_and_check(w)


def settle_and_check(w: Wire) -> None:
    """Settle (link up, everything dispatched, delivered and executed, what was refused
    dispatched again) and check the oracle."""
    if w.link is None:
        w.connect()
    for _ in range(500):
        if w.next < w.n:  # the rest of the plan, after what a refusal took back
            w.op("redispatch")
            for _ in range(w.n):
                w.op("dispatch")
        if not (w.to_robot or w.to_gw or w.body or w.robot.queue):
            if not any(k == "refused" for k in w.gw.applied.values()):
                break
            w.op("redispatch")
        for op in ("to_robot", "to_gateway", "step"):
            w.op(op)
    assert not w.gw.held, w.gw.held
    ends = [(aid, k) for aid, k in w.applied if k != "refused"]
    ids = [aid for aid, _ in ends]
    assert len(ids) == len(set(ids)) == w.n  # every action ended exactly once
    finished = sorted(int(a.split(".")[2]) for a, k in ends if k == "finished")
    assert w.executed == finished  # executed once each, in index order, only those


def test_the_wire_detects_a_robot_that_forgets_to_confirm() -> None:
    # the oracle can fail: a robot whose cancels are never confirmed leaves actions held
    w = Wire(3)
    w.connect()
    for op in ["dispatch", "dispatch", "cancel"]:
        w.op(op)
    w.to_robot.clear()  # the cancels are lost, the link stays up
    w.pump()
    assert set(w.gw.held) == {"0.0.0", "0.0.1"} and all(h.cancel for h in w.gw.held.values())
    assert not any(isinstance(m, Cancelled | Finished) for m in w.to_gw)
    assert w.robot.activity() is None  # it never got them: only a hello can settle this
    w.cut()
    w.connect()
    assert not w.gw.held and [k for _, k in w.applied] == ["cancelled", "cancelled"]


def test_a_v2_blocked_of_a_move_under_way_is_a_stop_on_the_way() -> None:
    for version, told in ((2, "stopped"), (1, "blocked")):
        gs = GatewaySession(0)
        link = object()
        n = next(_n)
        gs.hello(Hello(v=version, msg_id=f"h{n}", seq=0, robot_id=0), 0.0)
        gs.welcome(link, version=version, start=None, plan=0, state_period_ms=1e3,
                   paused=False)
        gs.dispatch(fields(0))
        gs.report("started", "0.0.0", "s", link, 1.0)
        accept_all(gs)
        gs.report("blocked", "0.0.0", "b", link, 2.0)  # a bumper
        (r,) = [e for e in accept_all(gs) if isinstance(e, Report)]
        assert r.kind == told and gs.held["0.0.0"].phase == "blocked"
        gs.report("unblocked", "0.0.0", "u", link, 3.0)
        accept_all(gs)
        assert gs.held["0.0.0"].phase == "running"  # it drives on


def test_a_v1_robot_is_refused_only_on_a_turning_plan() -> None:
    v1 = Hello(v=1, msg_id="h", seq=0, robot_id=0)
    v2 = Hello(v=2, msg_id="h", seq=0, robot_id=0)
    assert hello_refusal(v1, turning_plan=False) is None
    assert hello_refusal(v2, turning_plan=True) is None
    refusal = hello_refusal(v1, turning_plan=True)
    assert refusal is not None and "v2" in refusal


@pytest.mark.parametrize("version", [2, 3])
def test_a_refusal_of_a_queued_action_from_before_its_new_dispatch_is_dropped(version: int
                                                                             ) -> None:
    # the robot holds actions 0 and 1 (its hello on a new link said so) and its body refuses 0
    # when it is due: a v2 robot drops 1 silently (held, so acknowledged), a v3 robot refuses
    # it too; the gateway dispatches both again before that refusal of 1 arrives, which must
    # not take the new dispatch back
    w = Wire(2, cast(ProtocolVersion, version))
    w.connect()
    for op in ["dispatch", "dispatch", "to_robot", "to_robot", "to_robot",  # welcome, 0, 1
               "cut", "reconnect", "to_robot", "refuse"]:
        w.op(op)
    assert all(h.acked for h in w.gw.held.values())
    told = [(m.type, getattr(m, "action_id", None)) for m in w.to_gw]
    assert told == ([("refused", "0.0.0")] if version == 2
                    else [("refused", "0.0.0"), ("refused", "0.0.1")])
    while w.to_gw and w.to_gw[0].type != "refused":
        w.op("to_gateway")
    w.op("to_gateway")  # the refusal of 0 takes 0 and 1 back
    assert not w.gw.held
    w.op("redispatch")
    while w.to_gw:
        w.op("to_gateway")  # v3: the old refusal of 1
    assert set(w.gw.held) == {"0.0.0", "0.0.1"}
    for _ in range(20):
        for op in ("to_robot", "to_gateway", "step"):
            w.op(op)
    assert not w.gw.held and w.executed == [0, 1]
