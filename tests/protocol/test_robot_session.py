"""The robot side of the protocol (protocol.robot_session), fed by hand: the one behaviour both
robot implementations (robot_client and the simulated fleet) share.

The property test plays a gateway that dispatches a robot's actions in index order, duplicates,
cancels, pauses and cuts the link at random, and a body that executes what the session hands it;
its oracle is plain bookkeeping of the gateway's view: every action ends finished exactly once
or cancelled (confirmed), never both, and nothing is executed out of order.
"""

from __future__ import annotations

from typing import Any

from hypothesis import given, settings
from hypothesis import strategies as st

from protocol import (
    Action,
    ActionRefused,
    AnyMessage,
    CancelAction,
    Cancelled,
    Error,
    ErrorCode,
    Finished,
    Hello,
    Pause,
    Pose,
    Resume,
    Started,
    State,
    Welcome,
)
from protocol.robot_session import (
    HISTORY,
    Abort,
    GatewayError,
    Received,
    Refused,
    RobotEffect,
    RobotSession,
    Send,
    Welcomed,
)

_seq = iter(range(10**9))


def msg(kind: type[AnyMessage], **fields: Any) -> Any:
    n = next(_seq)
    return kind(msg_id=f"g-{n}", seq=n, **fields)


def action(i: int, plan: int = 0, robot: int = 0) -> Action:
    return msg(Action, action_id=f"{plan}.{robot}.{i}", sequence=i, src=Pose(cell=(i, 0)),
               dst=Pose(cell=(i + 1, 0)), duration_ms=1000.0)


def sent(effects: list[RobotEffect]) -> list[tuple[str, str | None]]:
    """(type, action_id) of every message sent."""
    return [(e.message.type, getattr(e.message, "action_id", None))
            for e in effects if isinstance(e, Send)]


def welcomed(s: RobotSession, **fields: Any) -> list[RobotEffect]:
    s.connected(Pose(cell=(0, 0)))
    s.receive(msg(Welcome, robot_id=s.robot_id, **fields))
    return s.drain()


def test_hello_then_welcome_then_acks_and_in_order_execution() -> None:
    s = RobotSession(0, version=2)
    s.connected(Pose(cell=(0, 0)))
    (hello,) = [e.message for e in s.drain() if isinstance(e, Send)]
    assert isinstance(hello, Hello) and hello.seq == 0 and hello.acked == []
    assert s.take() is None  # not welcomed yet
    s.receive(action(0))
    assert sent(s.drain()) == [("ack", "0.0.0")]
    assert s.take() is None  # still not welcomed: nothing starts
    s.receive(msg(Welcome, robot_id=0, resend=[action(0), action(1)]))
    effects = s.drain()
    assert isinstance(effects[0], Welcomed)
    assert sent(effects) == [("ack", "0.0.0"), ("ack", "0.0.1")]  # the resent 0 is a duplicate
    assert [e.duplicate for e in effects if isinstance(e, Received)] == [True, False]
    first = s.take()
    assert first is not None and first.action_id == "0.0.0"
    assert s.take() is None  # one at a time
    s.report("started", "0.0.0")
    s.report("finished", "0.0.0", Pose(cell=(1, 0)))
    nxt = s.take()
    assert nxt is not None and nxt.action_id == "0.0.1"
    out = s.drain()
    assert sent(out) == [("started", "0.0.0"), ("finished", "0.0.0")]
    seqs = [e.message.seq for e in out if isinstance(e, Send)]
    assert seqs == [4, 5]  # hello, three acks, then these: +1 per message on the link
    assert s.finished == ["0.0.0"]


def test_a_duplicate_is_acked_never_executed_twice_and_a_finished_one_is_reported_again(
) -> None:
    s = RobotSession(0, version=2)
    welcomed(s)
    s.receive(action(0))
    s.receive(action(0))
    assert sent(s.drain()) == [("ack", "0.0.0"), ("ack", "0.0.0")]
    assert s.duplicates == 1 and len(s.queue) == 1
    a = s.take()
    assert a is not None
    s.receive(action(0))  # while it runs
    s.report("started", "0.0.0")
    s.report("finished", "0.0.0", Pose(cell=(1, 0)))
    s.drain()
    s.receive(action(0))  # after it finished: the gateway has no finish for it
    assert sent(s.drain()) == [("ack", "0.0.0"), ("finished", "0.0.0")]
    assert s.take() is None and s.duplicates == 3


def test_cancel_drops_the_queued_actions_behind_it_each_confirmed_once() -> None:
    s = RobotSession(0, version=2)
    welcomed(s, paused=True)
    for i in range(4):
        s.receive(action(i))
    s.drain()
    s.receive(msg(CancelAction, action_id="0.0.1"))
    assert sent(s.drain()) == [("cancelled", "0.0.1"), ("cancelled", "0.0.2"),
                               ("cancelled", "0.0.3")]
    for i in (2, 3):  # the gateway's own cancels of those: stale, not confirmed again
        s.receive(msg(CancelAction, action_id=f"0.0.{i}"))
    s.receive(msg(CancelAction, action_id="7.0.0"))  # never held
    assert s.drain() == []
    assert [a.action_id for a in s.queue] == ["0.0.0"]
    s.receive(action(1))  # an abandoned replan dispatches it again: held again, in order
    assert sent(s.drain()) == [("ack", "0.0.1")]
    assert [a.action_id for a in s.queue] == ["0.0.0", "0.0.1"]


def test_cancel_of_the_current_action_only_while_it_waits_for_its_cell() -> None:
    s = RobotSession(0)
    welcomed(s)
    s.receive(action(0))
    s.receive(action(1))
    assert s.take() is not None
    s.report("blocked", "0.0.0")
    s.drain()
    s.receive(msg(CancelAction, action_id="0.0.0"))
    effects = s.drain()
    assert effects[0] == Abort("0.0.0")
    assert sent(effects) == [("cancelled", "0.0.0"), ("cancelled", "0.0.1")]
    assert s.current is None and not s.queue
    # a moving robot finishes instead
    s.receive(action(0))
    assert s.take() is not None
    s.report("started", "0.0.0")
    s.drain()
    s.receive(msg(CancelAction, action_id="0.0.0"))
    assert s.drain() == [] and s.current == "0.0.0"


def test_cancel_of_a_move_stopped_on_the_way_is_confirmed_once_the_body_is_back() -> None:
    s = RobotSession(0)
    welcomed(s)
    s.receive(action(0))
    s.receive(action(1))
    assert s.take() is not None
    s.report("started", "0.0.0")
    s.report("blocked", "0.0.0")  # a bumper: a stop on the way
    s.drain()
    s.receive(msg(CancelAction, action_id="0.0.0"))
    effects = s.drain()
    assert effects[0] == Abort("0.0.0", moved=True)
    assert sent(effects) == [("cancelled", "0.0.1")]  # the queue at once, not the move yet
    assert s.current == "0.0.0" and s.take() is None
    s.receive(msg(CancelAction, action_id="0.0.0"))  # repeated: already going back
    assert s.drain() == []
    s.aborted("0.0.1")  # not the current action: ignored
    assert s.drain() == []
    s.aborted("0.0.0", Pose(cell=(0, 0)))
    (confirm,) = [e.message for e in s.drain() if isinstance(e, Send)]
    assert isinstance(confirm, Cancelled) and confirm.pose == Pose(cell=(0, 0))
    assert s.current is None and s.activity() is None


def turn_or_move(i: int, src: tuple[int, int], h0: str, dst: tuple[int, int], h1: str,
                 plan: int = 0) -> Action:
    return msg(Action, action_id=f"{plan}.0.{i}", sequence=i, src=Pose(cell=src, heading=h0),
               dst=Pose(cell=dst, heading=h1), duration_ms=1000.0)


def refusals(effects: list[RobotEffect]) -> list[tuple[str, str]]:
    return [(e.message.action_id, e.message.code) for e in effects
            if isinstance(e, Send) and isinstance(e.message, ActionRefused)]


def test_an_action_that_does_not_start_where_the_robot_will_stand_is_refused() -> None:
    s = RobotSession(0, version=2)
    s.connected(Pose(cell=(0, 0), heading="E"))
    s.receive(msg(Welcome, robot_id=0))
    s.drain()
    s.receive(turn_or_move(0, (0, 0), "E", (0, 0), "N"))  # a turn: starts as the robot stands
    s.receive(turn_or_move(1, (0, 0), "E", (1, 0), "E"))  # but the turn ends facing N
    s.receive(turn_or_move(2, (1, 0), "E", (2, 0), "E"))  # behind a refused one
    effects = s.drain()
    assert sent(effects)[0] == ("ack", "0.0.0")
    assert refusals(effects) == [("0.0.1", "pose_mismatch"), ("0.0.2", "queued_behind")]
    (why,) = [e.message.detail for e in effects
              if isinstance(e, Send) and isinstance(e.message, ActionRefused)][:1]
    assert why == "it starts at [0, 0] facing E, but the robot will stand at [0, 0] facing N"
    assert [a.action_id for a in s.queue] == ["0.0.0"]
    # a replan's plan from where the robot will stand is taken; the cell counts too
    s.receive(turn_or_move(0, (0, 0), "N", (0, 1), "N", plan=1))
    s.receive(turn_or_move(1, (0, 2), "N", (0, 3), "N", plan=1))
    effects = s.drain()
    assert sent(effects)[0] == ("ack", "1.0.0")
    assert refusals(effects) == [("1.0.1", "pose_mismatch")]
    # an omni action (no heading) is checked on its cell only
    s.receive(msg(Action, action_id="1.0.1", sequence=1, src=Pose(cell=(0, 1)),
                  dst=Pose(cell=(0, 2)), duration_ms=1000.0))
    assert sent(s.drain()) == [("ack", "1.0.1")]


def test_an_action_the_body_cannot_start_when_due_is_refused_with_its_queue() -> None:
    s = RobotSession(0, version=2)
    s.connected(Pose(cell=(0, 0), heading="E"))
    s.receive(msg(Welcome, robot_id=0))
    s.receive(turn_or_move(0, (0, 0), "E", (1, 0), "E"))
    s.receive(turn_or_move(1, (1, 0), "E", (2, 0), "E"))
    s.drain()
    assert s.take() is not None
    s.refuse_current("pose_mismatch", "the robot faces N", Pose(cell=(0, 0), heading="N"))
    assert refusals(s.drain()) == [("0.0.0", "pose_mismatch")]
    assert s.current is None and not s.queue and s.take() is None
    s.receive(turn_or_move(2, (2, 0), "E", (3, 0), "E"))  # was in flight: refused too
    assert refusals(s.drain()) == [("0.0.2", "queued_behind")]


def test_a_v3_robot_acknowledges_with_its_first_report_and_answers_what_it_drops() -> None:
    s = RobotSession(0)  # the latest version: 3
    s.connected(Pose(cell=(0, 0)))
    (hello,) = [e.message for e in s.drain() if isinstance(e, Send)]
    assert isinstance(hello, Hello) and hello.v == 3
    s.receive(msg(Welcome, robot_id=0, resend=[action(0)]))
    s.receive(action(1))
    s.receive(action(1))  # a duplicate: nothing to say
    effects = s.drain()
    assert sent(effects) == [] and s.duplicates == 1
    assert [a.action_id for a in s.queue] == ["0.0.0", "0.0.1"]
    assert s.take() is not None
    s.report("started", "0.0.0")  # acknowledges it
    s.report("finished", "0.0.0", Pose(cell=(1, 0)))
    s.receive(action(0))  # after it finished: its finished again, no ack
    out = s.drain()
    assert sent(out) == [("started", "0.0.0"), ("finished", "0.0.0"), ("finished", "0.0.0")]
    assert [e.message.seq for e in out if isinstance(e, Send)] == [1, 2, 3]
    assert {e.message.v for e in out if isinstance(e, Send)} == {3}
    s.receive(action(2))
    s.receive(action(3))
    assert s.take() is not None  # 0.0.1; 2 and 3 queued behind it
    s.refuse_current("cannot_execute", "no battery")
    assert refusals(s.drain()) == [("0.0.1", "cannot_execute"), ("0.0.2", "queued_behind"),
                                   ("0.0.3", "queued_behind")]
    s.receive(action(2))  # a repeat of one refused behind it: refused again, not taken
    assert refusals(s.drain()) == [("0.0.2", "queued_behind")]
    s.receive(action(1))  # the refused one dispatched again: the chain is cleared
    s.receive(action(2))
    assert sent(s.drain()) == [] and [a.action_id for a in s.queue] == ["0.0.1", "0.0.2"]


def test_a_v1_or_v2_robot_speaks_its_version() -> None:
    for version in (1, 2):
        s = RobotSession(0, version=version)  # type: ignore[arg-type]
        welcomed(s)
        s.receive(action(0))
        assert s.take() is not None
        s.report("started", "0.0.0")
        out = [e.message for e in s.drain() if isinstance(e, Send)]
        assert [(m.type, m.v) for m in out] == [("ack", version), ("started", version)]


def test_pause_resume_and_a_link_loss_stop_new_starts() -> None:
    s = RobotSession(0)
    welcomed(s)
    s.receive(msg(Pause))
    s.receive(action(0))
    assert s.take() is None
    s.receive(msg(Resume))
    s.disconnected()
    assert s.take() is None  # not welcomed on a live link
    s.drain()
    s.connected()
    assert s.take() is None  # hello sent, not welcomed yet
    s.receive(msg(Welcome, robot_id=0))
    assert s.take() is not None


def test_reconnect_reports_what_the_link_loss_swallowed() -> None:
    s = RobotSession(0)
    welcomed(s)
    for i in range(3):
        s.receive(action(i))
    assert s.take() is not None
    s.report("started", "0.0.0")
    s.drain()
    s.disconnected()
    s.report("finished", "0.0.0", Pose(cell=(1, 0)))  # offline: nothing is sent
    assert s.take() is None and s.drain() == []
    s.connected()
    (hello,) = [e.message for e in s.drain() if isinstance(e, Send)]
    assert isinstance(hello, Hello)
    assert hello.finished == ["0.0.0"] and hello.acked == ["0.0.1", "0.0.2"]
    assert hello.current is not None and hello.current.action_id == "0.0.1"
    assert hello.current.state == "received" and hello.pose == Pose(cell=(1, 0))
    assert hello.seq == 0


def test_history_is_bounded_and_ids_stay_unique_across_links() -> None:
    s = RobotSession(0)
    welcomed(s)
    for i in range(HISTORY + 10):
        s.receive(action(i))
        assert s.take() is not None
        s.report("started", f"0.0.{i}")
        s.report("finished", f"0.0.{i}")
    assert len(s.finished) == HISTORY and s.finished[0] == "0.0.10"
    ids = [e.message.msg_id for e in s.drain() if isinstance(e, Send)]
    s.disconnected()
    s.connected()
    (hello,) = [e.message for e in s.drain() if isinstance(e, Send)]
    assert isinstance(hello, Hello) and len(hello.finished) == HISTORY
    Hello.model_validate(hello.model_dump())  # a valid message (at most 256 ids)
    assert hello.msg_id not in ids and len(set(ids)) == len(ids)


def test_state_snapshot_errors_and_refused_actions() -> None:
    def refuse_long(a: Action) -> None:
        if a.duration_ms > 5000:
            raise ValueError("too long")

    s = RobotSession(0, check=refuse_long)
    welcomed(s, state_period_ms=200.0)
    assert s.state_period_ms == 200.0
    bad = msg(Action, action_id="0.0.0", sequence=0, src=Pose(cell=(0, 0)),
              dst=Pose(cell=(1, 0)), duration_ms=9000.0)
    s.receive(bad)
    effects = s.drain()
    assert effects[0] == Refused(bad, "too long")  # not acknowledged, not held
    (refusal,) = [e.message for e in effects if isinstance(e, Send)]  # told (protocol v2)
    assert isinstance(refusal, ActionRefused) and refusal.action_id == "0.0.0"
    assert (refusal.code, refusal.detail) == ("cannot_execute", "too long")
    s.receive(action(0))
    assert s.take() is not None
    s.report("started", "0.0.0")
    s.state(battery=0.5, held_up=True)
    err = msg(Error, code=ErrorCode.DUPLICATE, ref="x")
    s.receive(err)
    effects = s.drain()
    snap = [e.message for e in effects if isinstance(e, Send)][-1]
    assert isinstance(snap, State) and snap.activity == "blocked" and snap.battery == 0.5
    assert snap.current is not None and snap.current.action_id == "0.0.0"
    assert effects[-1] == GatewayError(err)


# ---------------------------------------------------------------------------- property test
OPS = st.lists(st.sampled_from(["dispatch", "duplicate", "cancel", "step", "step", "step",
                                "pause", "resume", "cut", "reconnect"]), max_size=60)


class Gateway:
    """The gateway's view, as plain bookkeeping: what it dispatched and what it heard."""

    def __init__(self, n: int) -> None:
        self.n = n
        self.next = 0  # next index to dispatch
        self.outstanding: list[int] = []  # dispatched, neither finished, cancelled nor refused
        self.finished: list[int] = []
        self.cancelled: list[int] = []
        self.refused: list[int] = []  # taken back: after a cancel, the chain no longer fits
        self.cancelling: set[int] = set()

    def hear(self, effects: list[RobotEffect]) -> None:
        for e in effects:
            if not isinstance(e, Send):
                continue
            m = e.message
            if isinstance(m, Finished | Cancelled | ActionRefused):
                i = int(m.action_id.split(".")[2])
                if i in self.outstanding:  # the gateway applies each once
                    self.outstanding.remove(i)
                    done = {Finished: self.finished, Cancelled: self.cancelled}
                    done.get(type(m), self.refused).append(i)
            if isinstance(m, Started):
                i = int(m.action_id.split(".")[2])
                assert i not in self.cancelled, f"{i} started after its cancel was confirmed"

    def hello(self, hello: Hello) -> list[Action]:
        """Apply the hello's finishes; resend what the robot does not hold."""
        for aid in hello.finished:
            i = int(aid.split(".")[2])
            if i in self.outstanding:
                self.outstanding.remove(i)
                self.finished.append(i)
        held = set(hello.acked)
        return [action(i) for i in self.outstanding
                if f"0.0.{i}" not in held and i not in self.cancelling]


@settings(max_examples=150, deadline=None)
@given(OPS)
def test_random_interleavings_never_lose_or_double_an_action(ops: list[str]) -> None:
    s = RobotSession(0)
    gw = Gateway(12)
    body: str | None = None  # the action the body executes
    executed: list[int] = []
    s.connected()
    s.drain()
    s.receive(msg(Welcome, robot_id=0))
    s.drain()
    for op in ops:
        if op == "dispatch" and gw.next < gw.n:
            gw.outstanding.append(gw.next)
            if s.link_up:
                s.receive(action(gw.next))
            gw.next += 1
        elif op == "duplicate" and gw.outstanding and s.link_up:
            s.receive(action(gw.outstanding[-1]))
        elif op == "cancel" and gw.outstanding and s.link_up:
            victim = gw.outstanding[-1]
            gw.cancelling.add(victim)
            s.receive(msg(CancelAction, action_id=f"0.0.{victim}"))
        elif op == "step":
            if body is not None:
                s.report("finished", body)
                executed.append(int(body.split(".")[2]))
                body = None
            else:
                a = s.take()
                if a is not None:
                    body = a.action_id
                    s.report("started", body)
        elif op == "pause" and s.link_up:
            s.receive(msg(Pause))
        elif op == "resume" and s.link_up:
            s.receive(msg(Resume))
        elif op == "cut":
            s.disconnected()
        elif op == "reconnect" and not s.link_up:
            s.connected()
            (hello,) = [e.message for e in s.drain() if isinstance(e, Send)]
            assert isinstance(hello, Hello)
            resend = gw.hello(hello)
            s.receive(msg(Welcome, robot_id=0, resend=resend))
        gw.hear(s.drain())
    assert executed == sorted(executed) and len(set(executed)) == len(executed)
    # drain: reconnect, resume, and run everything to the end
    if not s.link_up:
        s.connected()
        (hello,) = [e.message for e in s.drain() if isinstance(e, Send)]
        s.receive(msg(Welcome, robot_id=0, resend=gw.hello(hello)))
    s.receive(msg(Resume))
    if body is not None:
        s.report("finished", body)
        executed.append(int(body.split(".")[2]))
    while (a := s.take()) is not None:
        s.report("started", a.action_id)
        s.report("finished", a.action_id)
        executed.append(int(a.action_id.split(".")[2]))
    gw.hear(s.drain())
    assert gw.outstanding == []  # nothing lost
    # each exactly once: finished, cancelled, or refused (taken back by the gateway)
    assert sorted(gw.finished + gw.cancelled + gw.refused) == list(range(gw.next))
    # a robot refuses only an action that no longer starts where it will stand: one queued
    # after a cancelled action (the chain of actions 0, 1, 2, ... fits otherwise)
    assert all(any(c < r for c in gw.cancelled) for r in gw.refused), (gw.cancelled, gw.refused)
    assert len(executed) == len(set(executed)) and set(executed) == set(gw.finished)
    assert executed == sorted(executed)  # index order


def test_a_v3_robot_refused_as_unsupported_says_hello_again_in_v2() -> None:
    s = RobotSession(0)
    s.connected(Pose(cell=(0, 0)))
    (hello,) = [e.message for e in s.drain() if isinstance(e, Send)]
    assert hello.v == 3
    s.receive(msg(Error, code=ErrorCode.UNSUPPORTED_VERSION, ref="someone-else"))
    assert [type(e) for e in s.drain()] == [GatewayError]  # not about its hello: passed on
    s.receive(msg(Error, code=ErrorCode.UNSUPPORTED_VERSION, ref=hello.msg_id))
    (again,) = [e.message for e in s.drain() if isinstance(e, Send)]
    assert isinstance(again, Hello) and again.v == 2 and again.msg_id != hello.msg_id
    s.receive(msg(Welcome, robot_id=0))
    s.receive(action(0))
    assert [(e.message.type, e.message.v) for e in s.drain() if isinstance(e, Send)] == [
        ("ack", 2)]  # a v2 robot from now on
    s.receive(msg(Error, code=ErrorCode.UNSUPPORTED_VERSION, ref=again.msg_id))
    assert [type(e) for e in s.drain()] == [GatewayError]  # v2 is as low as it goes
