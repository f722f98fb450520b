"""A robot refuses actions during a lifelong shift: the sans-I/O lifelong executor, the
gateway's protocol sessions and the robots' protocol sessions wired together by hand, with
messages in flight both ways delivered one at a time in a random order (per robot in order,
as on one websocket), segments adopted while robots move, bodies that refuse an action on
arrival (``cannot_execute``) or when it is due (``refuse_current``), and links that are cut
and come back.

Oracle: the robots' bodies executed every action the executor counts finished, once each,
in order and nothing else (nothing lost, nothing duplicated); nobody got an ``error``; the
independent trace checker accepts the trace (no collision, every start after its
dependencies, a refused action taken back before it ran); and a refused action is dispatched
again with the same id.
"""

from __future__ import annotations

from collections import deque
from typing import Any, cast

from hypothesis import given, settings
from hypothesis import strategies as st

from gateway.execution.commands import Completed, Dispatch
from gateway.execution.errors import ExecutionError
from gateway.execution.lifelong.errands import TaskDistances
from gateway.execution.lifelong.executor import LifelongExecutor, PlanRequest, WindowPlanner
from gateway.execution.lifelong.tasks import TaskPool
from gateway.execution.trace_records import summary_record
from protocol import (
    Ack,
    Action,
    ActionRefused,
    AnyMessage,
    Hello,
    Pose,
    State,
    action_id,
)
from protocol.gateway_session import GatewaySession, Refuse, Report, ToRobot
from protocol.messages import HEADINGS, ProtocolVersion
from protocol.robot_session import GatewayError, RobotSession, Send
from tests.lifelong.support import small_problem
from tracecheck import check_trace

RUN = "r1"


def _heading(h: int | None) -> Any:
    return None if h is None else HEADINGS[h]


class Shift:
    """A lifelong executor, one gateway session and one robot session per robot, the links
    between them (FIFO queues each way) and the robots' bodies."""

    def __init__(self, seed: int, robots: int, turning: bool, lookahead: int,
                 version: ProtocolVersion = 3) -> None:
        prob = small_problem(seed, robots=robots, size=8, p_delay=0.0)
        self.grid = prob.grid
        self.records: list[dict[str, Any]] = []
        self.ex = LifelongExecutor(
            prob.grid, prob.starts, [0] * robots if turning else None,
            TaskPool(prob.tasks, robots + 2), distances=TaskDistances(prob.grid),
            lookahead=lookahead, period_ms=1000.0, record=self.records.append)
        self.planner = WindowPlanner(prob.grid, robots, turning, seed)
        self.request: PlanRequest | None = None
        self.n = robots
        self.gs = [GatewaySession(r) for r in range(robots)]
        self.flaky = [False] * robots  # the body refuses the next action it is sent
        self.version = version
        self.rs = [RobotSession(r, check=self._checker(r), version=version)
                   for r in range(robots)]
        self.to_robot: list[deque[AnyMessage]] = [deque() for _ in range(robots)]
        self.to_gateway: list[deque[AnyMessage]] = [deque() for _ in range(robots)]
        self.links = [0] * robots  # the gateway's handle of each robot's connection
        self.body: list[Action | None] = [None] * robots
        self.moving = [False] * robots
        self.executed: list[list[int]] = [[] for _ in range(robots)]
        self.dispatched: list[tuple[int, int]] = []
        self.errors: list[str] = []
        self.now = 0.0
        self.completed = False
        self._ids = 0

    def _checker(self, r: int) -> Any:
        def check(_: Action) -> None:
            if self.flaky[r]:
                self.flaky[r] = False
                raise ValueError("the body cannot now")
        return check

    # ------------------------------------------------------------------ the gateway side
    def pose(self, r: int) -> Pose:
        cell, heading = self.ex.pose(r)
        return Pose(cell=self.grid.cell(cell), heading=_heading(heading))

    def flush(self, r: int) -> None:
        """Carry out gateway session r's effects (as the engine does)."""
        gs = self.gs[r]
        while effects := gs.drain():
            for e in effects:
                if isinstance(e, ToRobot):
                    if gs.link is not None:
                        self._ids += 1
                        self.to_robot[r].append(e.kind(msg_id=f"g{self._ids}", seq=0,
                                                       **e.fields))
                elif isinstance(e, Refuse):
                    self.errors.append(f"gateway to robot {r}: {e.code} {e.detail}")
                else:
                    self.apply(gs, e)

    def apply(self, gs: GatewaySession, rep: Report) -> None:
        ex = self.ex
        handlers = {"started": ex.started, "finished": ex.finished, "blocked": ex.blocked,
                    "stopped": ex.stopped, "unblocked": ex.unblocked,
                    "cancelled": ex.cancelled}
        try:
            if rep.kind == "refused":
                ex.refused(rep.robot, rep.plan, rep.index, rep.t_ms, rep.reason)
            else:
                handlers[rep.kind](rep.robot, rep.plan, rep.index, rep.t_ms)
        except ExecutionError as exc:
            gs.rejected(rep, str(exc))
            return
        gs.accepted(rep)
        self.route()

    def route(self) -> None:
        for c in self.ex.drain():
            if isinstance(c, Dispatch):
                self.dispatched.append((c.robot, c.action))
                gs = self.gs[c.robot]
                gs.dispatch({
                    "action_id": action_id(c.plan, c.robot, c.action, RUN),
                    "sequence": c.action,
                    "src": Pose(cell=c.src, heading=_heading(c.src_heading)),
                    "dst": Pose(cell=c.dst, heading=_heading(c.dst_heading)),
                    "duration_ms": c.duration_ms})
                self.flush(c.robot)
            elif isinstance(c, PlanRequest):
                self.request = c
            elif isinstance(c, Completed):
                self.completed = True

    def receive(self, r: int, m: AnyMessage) -> None:
        """The gateway handles one message of robot r."""
        gs, link = self.gs[r], self.links[r]
        if isinstance(m, Hello):
            gs.hello(m, self.now)
            self.flush(r)
            gs.welcome(link, version=self.version, start=self.pose(r), plan=None,
                       state_period_ms=5000.0, paused=False)
        elif isinstance(m, Ack):
            gs.ack(m.action_id, m.msg_id, link)
        elif not isinstance(m, State):
            reason = f"{m.code}: {m.detail}" if isinstance(m, ActionRefused) else ""
            gs.report(m.type, m.action_id, m.msg_id, link, self.now, m.pose, reason)
        self.flush(r)

    # ------------------------------------------------------------------ the robot side
    def robot_effects(self, r: int) -> None:
        for e in self.rs[r].drain():
            if isinstance(e, Send):
                self.to_gateway[r].append(e.message)
            elif isinstance(e, GatewayError):
                self.errors.append(f"robot {r} got {e.message.code} {e.message.detail}")

    def connect(self, r: int) -> None:
        self.links[r] += 1
        rs = self.rs[r]
        rs.connected(rs.pose or self.pose(r))
        self.robot_effects(r)

    def cut(self, r: int) -> None:
        """The link goes down: what is in flight is lost."""
        self.rs[r].disconnected()
        self.gs[r].disconnected(self.links[r])
        self.to_robot[r].clear()
        self.to_gateway[r].clear()

    def step(self, r: int) -> None:
        """The body takes its next action, starts it, or finishes it."""
        rs, a = self.rs[r], self.body[r]
        if a is None:
            self.body[r] = rs.take()
        elif not self.moving[r]:
            self.moving[r] = True
            rs.report("started", a.action_id)
        else:
            self.body[r], self.moving[r] = None, False
            self.executed[r].append(a.sequence)
            rs.report("finished", a.action_id, a.dst)
        self.robot_effects(r)

    def refuse_due(self, r: int) -> None:
        """The body finds it cannot start the action it took."""
        if self.body[r] is not None and not self.moving[r]:
            self.body[r] = None
            self.rs[r].refuse_current("cannot_execute", "the wheels are locked")
            self.robot_effects(r)

    # ------------------------------------------------------------------ ops
    def op(self, kind: str, r: int) -> None:
        self.now += 5.0
        if kind == "to_robot" and self.to_robot[r]:
            self.rs[r].receive(self.to_robot[r].popleft())
            self.robot_effects(r)
        elif kind == "to_gateway" and self.to_gateway[r]:
            self.receive(r, self.to_gateway[r].popleft())
        elif kind == "step":
            self.step(r)
        elif kind == "flaky":
            self.flaky[r] = True
        elif kind == "refuse":
            self.refuse_due(r)
        elif kind == "cut" and self.rs[r].link_up:
            self.cut(r)
        elif kind == "reconnect" and not self.rs[r].link_up:
            self.connect(r)
        elif kind in ("tick", "period"):
            self.now += 300.0 if kind == "tick" else 1000.0
            self.ex.tick(self.now)
            self.route()
        elif kind == "plan" and self.request is not None:
            req, self.request = self.request, None
            self.ex.adopt(self.planner(req), self.now)
            self.route()

    def settle(self) -> None:
        """Reconnect every robot, run until the shift (stopped after a while) is done."""
        self.flaky = [False] * self.n
        for r in range(self.n):
            if not self.rs[r].link_up:
                self.connect(r)
        stop_at = self.now + 5000.0
        for _ in range(5000):
            if self.completed:
                return
            for r in range(self.n):
                while self.to_robot[r] or self.to_gateway[r]:
                    self.op("to_robot", r)
                    self.op("to_gateway", r)
                self.op("step", r)
            self.op("tick", 0)
            self.op("plan", 0)
            if self.ex.mode.value == "running" and self.now >= stop_at:
                self.ex.stop(self.now)
                self.route()
        raise AssertionError("the stopped shift never completed")


def start(seed: int, robots: int = 3, turning: bool = True, lookahead: int = 1,
          version: ProtocolVersion = 3) -> Shift:
    """A shift whose robots (speaking protocol ``version``) said hello and were welcomed, its
    first planning call out."""
    s = Shift(seed, robots, turning, lookahead, version)
    for r in range(robots):
        s.connect(r)
        s.op("to_gateway", r)  # hello
        s.op("to_robot", r)  # welcome
    s.ex.start(s.now)
    s.route()
    return s


def check(s: Shift) -> None:
    """The oracle (see the module doc)."""
    assert s.errors == []
    for r in range(s.n):
        assert s.executed[r] == list(range(s.ex.adg.done[r])), (r, s.executed[r])
        assert s.gs[r].held == {}
    s.records.append(summary_record(sum(s.ex.completion), max(s.ex.completion)))
    report = check_trace(s.records)
    assert report.ok, (report.errors[:5], report.collisions[:5])
    # every refused action was dispatched again and run (the shift ran for periods after
    # the last refusal before it was stopped)
    refused = {(rec["robot"], rec["action"]) for rec in s.records if rec["type"] == "refused"}
    finished = {(rec["robot"], rec["action"]) for rec in s.records if rec["type"] == "finish"}
    assert refused <= finished, refused - finished
    assert all(s.dispatched.count(a) >= 2 for a in refused)


OPS = st.lists(st.tuples(
    st.sampled_from(["to_robot", "to_robot", "to_gateway", "to_gateway", "step", "step",
                     "flaky", "refuse", "cut", "reconnect", "tick", "period", "plan",
                     "plan"]),
    st.integers(0, 2)), min_size=100, max_size=300)


@settings(max_examples=100, deadline=None)
@given(seed=st.integers(0, 1000), turning=st.booleans(), lookahead=st.integers(0, 2),
       ops=OPS, version=st.sampled_from([2, 3]))
def test_random_refusals_lose_and_duplicate_nothing(seed: int, turning: bool, lookahead: int,
                                                   ops: list[tuple[str, int]], version: int
                                                   ) -> None:
    s = start(seed, turning=turning, lookahead=lookahead,
              version=cast(ProtocolVersion, version))
    for kind, r in ops:
        s.op(kind, r)
    s.settle()
    check(s)


def test_a_refused_action_is_dispatched_again_at_the_next_planning_call() -> None:
    s = start(4, robots=3, lookahead=1)
    s.op("plan", 0)
    busy = next(r for r in range(3) if s.to_robot[r])
    s.flaky[busy] = True  # it refuses the first action it gets, and those behind it
    first = s.to_robot[busy][0]
    assert isinstance(first, Action)
    held = len(s.to_robot[busy])
    for _ in range(held):
        s.op("to_robot", busy)
    for _ in range(held):
        s.op("to_gateway", busy)
    assert s.gs[busy].held == {} and s.ex.busy(busy) == 0  # taken back, no error
    assert next(rec["action"] for rec in s.records
                if rec["type"] == "refused" and rec["robot"] == busy) == first.sequence
    s.op("tick", 0)  # before the period is over: nothing yet
    assert not s.to_robot[busy]
    for _ in range(3):
        s.op("tick", 0)
    again = s.to_robot[busy][0]
    assert isinstance(again, Action) and again.action_id == first.action_id
    assert again.src == first.src
    s.settle()
    check(s)
    assert s.executed[busy][0] == first.sequence


def test_a_late_refusal_of_a_taken_back_action_is_not_taken_for_its_new_dispatch() -> None:
    """The robot refused actions k and k + 1; the gateway took both back on the refusal of k
    and dispatched them again (the next planning call) before the refusal of k + 1 arrived:
    that refusal is about the old dispatch, and the robot runs the new one."""
    s = start(4, robots=3, lookahead=1)
    s.op("plan", 0)
    for _ in range(4):
        s.op("tick", 0)
    s.op("plan", 0)  # k and k + 1 come from two segments
    busy = 1
    assert len(s.to_robot[busy]) == 2
    s.flaky[busy] = True
    s.op("to_robot", busy)
    s.op("to_robot", busy)
    assert [type(m) for m in s.to_gateway[busy]] == [ActionRefused, ActionRefused]
    s.op("to_gateway", busy)  # the refusal of k: k and k + 1 are taken back
    for _ in range(4):
        s.op("tick", 0)
    assert len(s.to_robot[busy]) == 2  # dispatched again
    while s.to_gateway[busy] or s.to_robot[busy]:  # the late refusal, then the new copies
        s.op("to_gateway", busy)
        s.op("to_robot", busy)
    for _ in range(6):  # the robot runs k and k + 1 before the next planning call
        s.op("step", busy)
        while s.to_gateway[busy]:
            s.op("to_gateway", busy)
    assert s.errors == []
    assert s.executed[busy] == [0, 1] and s.ex.adg.done[busy] == 2
    s.settle()
    check(s)
