"""The hello reconciliation after a journal lost its last records (issue 26, defects 2 and 5):
every finish the hello lists is applied, also of actions the gateway dispatches only during
the catch-up or later; no action is both resent and dropped; a robot that implements only the
MUST rules (no repeated ``finished``) is never stuck; actions of an abandoned run are in the
welcome's ``drop`` and a robot drops them before it can start anything."""

from __future__ import annotations

from typing import Any

from protocol import Action, CancelAction, Hello, Pose, Welcome
from protocol.gateway_session import GatewaySession, Refuse, Report, ToRobot
from protocol.messages import Activity
from protocol.robot_session import RobotSession, Send

RUN = "ab12cd34"


def fields(i: int, run: str = RUN) -> dict[str, Any]:
    return {"action_id": f"{run}.0.0.{i}", "sequence": i, "src": Pose(cell=(i, 0)),
            "dst": Pose(cell=(i + 1, 0)), "duration_ms": 1000.0}


def aid(i: int, run: str = RUN) -> str:
    return f"{run}.0.0.{i}"


class Chain:
    """A stand-in executor for one robot: finishing action i dispatches action i + 1 (the ADG
    of a lone robot), a finish of an action not dispatched is rejected."""

    def __init__(self, gs: GatewaySession, n: int) -> None:
        self.gs, self.n = gs, n
        self.dispatched: list[int] = []
        self.finished: list[int] = []
        self.out: list[Any] = []

    def dispatch(self, i: int) -> None:
        self.dispatched.append(i)
        self.gs.dispatch(fields(i))

    def flush(self) -> None:
        while effects := self.gs.drain():
            for e in effects:
                self.out.append(e)
                if not isinstance(e, Report):
                    continue
                if e.kind == "finished":
                    if e.index in self.finished or e.index not in self.dispatched:
                        self.gs.rejected(e, "not dispatched")
                        continue
                    self.finished.append(e.index)
                    self.gs.accepted(e)
                    if e.index + 1 < self.n:
                        self.dispatch(e.index + 1)
                else:
                    self.gs.accepted(e)


def _hello(**kw: Any) -> Hello:
    return Hello(msg_id="h", seq=0, robot_id=0, **kw)


def _welcome(c: Chain, link: object) -> Welcome:
    c.gs.welcome(link, version=2, start=None, plan=0, state_period_ms=100.0, paused=False)
    c.flush()
    (w,) = [e.fields for e in c.out if isinstance(e, ToRobot) and e.kind is Welcome]
    return Welcome(msg_id="w", seq=0, **w)


def test_finishes_of_actions_dispatched_during_the_catch_up_are_applied() -> None:
    """The journal lost the finishes of actions 0 and 1 (and so the dispatch of 1 and 2): the
    robot finished 0 and 1 and holds 2. Both finishes are applied, 2 is taken as held (not
    resent, not dropped), nothing is refused."""
    gs = GatewaySession(0)
    c = Chain(gs, 5)
    c.dispatch(0)  # what the replayed journal holds
    gs.hello(_hello(finished=[aid(0), aid(1)], acked=[aid(2)]), 10.0, run=RUN, plan=0)
    c.flush()
    welcome = _welcome(c, object())
    assert c.finished == [0, 1] and c.dispatched == [0, 1, 2]
    assert welcome.resend == [] and welcome.drop == []
    assert not [e for e in c.out if isinstance(e, Refuse)]
    assert gs.held[aid(2)].acked


def test_a_finish_reported_before_its_dispatch_is_kept_not_refused() -> None:
    """A robot that implements only the MUST rules reports the finish of an action the
    gateway has not dispatched again yet (its dispatch waits for a finish another robot still
    has to bring): the report is kept and applied with the dispatch, so the robot need not
    repeat it, and it is never both resent and cancelled."""
    gs = GatewaySession(0)
    c = Chain(gs, 5)
    gs.hello(_hello(acked=[aid(0)], current=Activity(action_id=aid(0), state="running")),
             10.0, run=RUN, plan=0)
    c.flush()
    link = object()
    welcome = _welcome(c, link)
    assert welcome.drop == [] and welcome.resend == []
    gs.report("finished", aid(0), "f0", link, 12.0)
    c.flush()
    assert not [e for e in c.out if isinstance(e, Refuse)]
    assert c.finished == []
    c.dispatch(0)  # the other robot's finish came back: the executor dispatches 0 again
    c.flush()
    assert c.finished == [0] and c.dispatched == [0, 1]
    sent = [e.fields["action_id"] for e in c.out if isinstance(e, ToRobot) and e.kind is Action]
    assert sent == [aid(1)]  # 0 was not sent again: the robot did it


def test_actions_of_an_abandoned_run_are_dropped_before_the_robot_can_start_them() -> None:
    """After ``--fresh`` the robot holds actions of the old run: they are in the welcome's
    ``drop``, and the robot's session drops them while it handles the welcome, before the
    body can take one."""
    robot = RobotSession(0)
    robot.connected(Pose(cell=(0, 0)))
    robot.receive(Welcome(msg_id="w0", seq=0, robot_id=0))
    old = [Action(msg_id=f"a{i}", seq=i + 1, **fields(i, "0ld0run0")) for i in range(3)]
    for a in old:
        robot.receive(a)
    robot.disconnected()
    robot.drain()
    robot.connected(Pose(cell=(0, 0)))
    (sent,) = [e.message for e in robot.drain() if isinstance(e, Send)]
    assert isinstance(sent, Hello)

    gs = GatewaySession(0)
    c = Chain(gs, 3)
    gs.hello(sent, 0.0, run=RUN, plan=0)
    c.flush()
    welcome = _welcome(c, object())
    assert welcome.drop == sorted(a.action_id for a in old)
    cancels = [e.fields["action_id"] for e in c.out
               if isinstance(e, ToRobot) and e.kind is CancelAction]
    assert sorted(cancels) == welcome.drop  # for robots that predate ``drop``
    robot.receive(welcome)
    assert robot.take() is None  # nothing of the old run can start
    assert not robot.queue
