"""fleetgate wire protocol v3 (serving v1 and v2): pydantic models for robot, gateway and
operator messages.

One JSON object per websocket text frame, discriminated on ``type``; every message has ``v``
(= :data:`PROTOCOL_VERSION`), a unique ``msg_id`` and a per-sender ``seq``; unknown fields are
refused; at most :data:`MAX_MESSAGE_BYTES`. Decode with :func:`decode` (raises
:class:`ProtocolError` carrying an :class:`ErrorCode`), encode with :func:`encode`.

Roles are fixed at the websocket handshake by the token (``Authorization: Bearer <token>`` or
``?token=``): a robot token is bound to one ``robot_id``; operator and world tokens have their
own role. A message that its sender's role may not send is refused with ``forbidden``.

Both ends of the robot session are sans-I/O state machines in this package, written once:
:class:`protocol.robot_session.RobotSession` (every robot implementation) and
:class:`protocol.gateway_session.GatewaySession` (the gateway, one per robot).

Robot session (borrowed from VDA 5050: release only what may be driven now, explicit
cancel/pause/resume, state snapshots that make reconnecting simple, coded rejections)::

    robot                                   gateway
      hello(robot_id, pose, acked, finished, current) -->
                                          <-- welcome(start pose, plan, resend[actions], paused)
                                          <-- action(action_id "run.plan.robot.i", src, dst,
                                                     duration_ms, sequence=i)
      ack(action_id)                        -->   v1, v2 only (robot drops a duplicate silently)
      blocked(action_id, pose)              -->   target cell taken; re-check ...
      unblocked(action_id, pose)            -->
      started(action_id, pose)              -->   begins to move (v3: acknowledges the action)
      finished(action_id, pose)             -->   arrived; applied once per action_id
                                          <-- action(...)  next one (see "Action queue")
                                          <-- cancel(action_id)   replan: drop it if not moving
      cancelled(action_id, pose)            -->   (or finished, if it was already moving)
      refused(action_id, code, detail, pose) -->  v2: will not execute it (instead of ack or
                                                  started), nor what follows it in the plan
                                                  (v3: each action dropped with it refused too)
                                          <-- pause / resume
      state(robot_id, pose, activity, current) every welcome.state_period_ms
                                          <-- error(code, ref=offending msg_id, detail)

Messages per action: v1 and v2 robots send ``ack``, ``started`` and ``finished``; a v3 robot
sends no ``ack`` (its first report about an action acknowledges it; an action it holds
without a report yet is in its ``hello.acked`` if the link drops, as in every version), so
the gateway handles three messages per action instead of four. Each connection speaks the
version of its robot's ``hello``.

Action queue (lookahead dispatch, as a VDA 5050 order releases the part a robot may drive): a
robot may hold a queue of actions. The gateway sends action i+1 of a robot once its
dependencies on other robots are done and action i has been sent (``dispatch_lookahead`` caps
how many are held beyond the current one; 0 = only when action i has finished). A robot MUST
execute its actions strictly in the order of their index and start action i+1 only after it
finished action i; the gateway refuses (``rejected``) a report about an action queued behind
one that has not finished. A ``cancel`` of a queued action also voids every action queued
behind it (the gateway cancels all of them at once; each is confirmed with ``cancelled``).
The gateway resends, in ``welcome.resend`` and in index order, only the dispatched actions it has
no ``finished`` for that the robot's ``hello`` does not report holding (``acked`` or
``current``): an acknowledged action the robot still holds is never sent twice, one it lost is.
On link loss a robot
finishes its current move and stops; the gateway holds that robot's ADG steps until it is back.
A ``finished`` for an action already applied gets ``error(duplicate)`` and changes nothing;
``hello.finished`` lets a robot report finishes whose messages were lost.

Operator session::

    operator                                gateway
                                          <-- snapshot (whole fleet), then a stream of event
      load_instance | load_plan | start | pause | resume | replan_now | set_policy
      | set_threshold | set_speed | place_intruder | get_snapshot -->
                                          <-- ok(ref) or error(code, ref)

World session (the simulated world of a demo): the gateway forwards ``place_intruder`` and
``set_speed`` to it; it reports ``intruder(cell, on|off)``, which the gateway relays to
operators as ``event(intruder)``. The executor never learns where the intruder is.
"""

from protocol.codec import (
    MESSAGE_ADAPTER,
    MESSAGE_TYPES,
    OPERATOR_TYPES,
    ROBOT_TYPES,
    WORLD_TYPES,
    ProtocolError,
    action_body,
    action_text,
    decode,
    encode,
    encode_action,
)
from protocol.messages import (
    MAX_MESSAGE_BYTES,
    PROTOCOL_VERSION,
    Ack,
    Action,
    ActionCounts,
    ActionRefused,
    Activity,
    AnyMessage,
    Blocked,
    CancelAction,
    Cancelled,
    CloseCode,
    Error,
    ErrorCode,
    Event,
    Finished,
    GenerateParams,
    GetSnapshot,
    Hello,
    IntruderReport,
    LoadInstance,
    LoadPlan,
    Message,
    Ok,
    OperatorCommand,
    Pause,
    PlaceIntruder,
    Pose,
    ReplanMark,
    ReplanNow,
    Resume,
    RobotMessage,
    RobotView,
    SetPolicy,
    SetSpeed,
    SetThreshold,
    Snapshot,
    Start,
    Started,
    State,
    StopShift,
    ToOperatorMessage,
    ToRobotMessage,
    Unblocked,
    WaitEdge,
    Welcome,
    WorldMessage,
    action_id,
    action_run,
    parse_action_id,
)
from protocol.schema import json_schema

__all__ = [
    "MAX_MESSAGE_BYTES",
    "MESSAGE_ADAPTER",
    "MESSAGE_TYPES",
    "OPERATOR_TYPES",
    "PROTOCOL_VERSION",
    "ROBOT_TYPES",
    "WORLD_TYPES",
    "Ack",
    "Action",
    "ActionCounts",
    "ActionRefused",
    "Activity",
    "AnyMessage",
    "Blocked",
    "CancelAction",
    "Cancelled",
    "CloseCode",
    "Error",
    "ErrorCode",
    "Event",
    "Finished",
    "GenerateParams",
    "GetSnapshot",
    "Hello",
    "IntruderReport",
    "LoadInstance",
    "LoadPlan",
    "Message",
    "Ok",
    "OperatorCommand",
    "Pause",
    "PlaceIntruder",
    "Pose",
    "ProtocolError",
    "ReplanMark",
    "ReplanNow",
    "Resume",
    "RobotMessage",
    "RobotView",
    "SetPolicy",
    "SetSpeed",
    "SetThreshold",
    "Snapshot",
    "Start",
    "Started",
    "State",
    "StopShift",
    "ToOperatorMessage",
    "ToRobotMessage",
    "Unblocked",
    "WaitEdge",
    "Welcome",
    "WorldMessage",
    "action_body",
    "action_id",
    "action_run",
    "action_text",
    "decode",
    "encode",
    "encode_action",
    "json_schema",
    "parse_action_id",
]
