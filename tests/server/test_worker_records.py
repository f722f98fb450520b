"""The records between worker processes and the owner (gateway/server/workers/records.py): every
robot message a worker admits crosses the channel's real framing (marshal) and arrives with
the fields the owner uses; the compact shapes cover every field of the messages they carry,
so a field added to one of them fails here rather than being dropped on the way."""

from __future__ import annotations

import asyncio
import itertools

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from gateway.server.workers.channel import Channel, batch_of, frame
from gateway.server.workers.records import (
    MESSAGE,
    REPORT,
    REPORT_TYPES,
    STATE,
    Op,
    event,
    message,
    pose,
)
from protocol import AnyMessage, Pose, State
from tests.protocol.samples import samples

ROBOT_TYPES = {"hello", "ack", "started", "finished", "blocked", "unblocked", "cancelled",
               "refused", "state"}


def _across(ops: list[Op]) -> list[Op]:
    """``ops`` after one trip through the channel's framing."""
    async def go() -> list[Op]:
        got: list[list[Op]] = []
        Channel(lambda payload: got.append(batch_of(payload))).data_received(frame(ops))
        [batch] = got
        return batch

    return asyncio.run(go())


def test_the_compact_shapes_carry_every_field_of_their_messages() -> None:
    envelope = {"type", "v", "msg_id", "seq"}
    for kind in REPORT_TYPES:  # v: the connection's (its hello's); seq: not used by the owner
        assert set(kind.model_fields) == envelope | {"action_id"} | (
            set() if kind.__name__ == "Ack" else {"pose"}), kind
    # a state: the owner keeps only its pose (GatewaySession.state)
    assert set(State.model_fields) == envelope | {"robot_id", "pose", "activity", "current",
                                                  "battery"}


@pytest.mark.parametrize("sent", [m for m in samples() if m.type in ROBOT_TYPES],
                         ids=lambda m: m.type)
def test_every_robot_message_crosses_with_what_the_owner_uses(sent: AnyMessage) -> None:
    [op] = _across([event(7, sent, 12.5)])
    assert op[1] == 7 and op[2] == 12.5
    if type(sent) in REPORT_TYPES:
        assert op[0] == REPORT
        assert op[3:6] == (sent.type, sent.msg_id, sent.action_id)  # type: ignore[union-attr]
        assert pose(*op[6:9]) == getattr(sent, "pose", None)
    elif isinstance(sent, State):
        assert op[0] == STATE and pose(*op[3:6]) == sent.pose
    else:  # hello, refused: the whole message
        assert op[0] == MESSAGE and message(op) == sent


@settings(max_examples=60, deadline=None)
@given(kind=st.sampled_from(sorted(REPORT_TYPES, key=lambda k: k.__name__)),
       msg_id=st.text(min_size=1, max_size=64),
       ids=st.tuples(st.integers(0, 10**6), st.integers(0, 10**6), st.integers(0, 10**6)),
       cell=st.none() | st.tuples(st.integers(0, 10**5), st.integers(0, 10**5)),
       heading=st.sampled_from([None, "E", "N", "W", "S"]))
def test_reports_cross_unchanged(kind: type[AnyMessage], msg_id: str,
                                 ids: tuple[int, int, int], cell: tuple[int, int] | None,
                                 heading: str | None) -> None:
    fields = {"msg_id": msg_id, "seq": 3, "action_id": "r1.{}.{}.{}".format(*ids)}
    if kind.__name__ != "Ack":
        fields["pose"] = None if cell is None else Pose(cell=cell, heading=heading)
    sent = kind(**fields)
    [op] = _across([event(1, sent, 0.0)])
    assert op[3:6] == (sent.type, msg_id, fields["action_id"])
    assert pose(*op[6:9]) == fields.get("pose")


@settings(max_examples=80, deadline=None)
@given(batches=st.lists(st.lists(st.tuples(st.integers(0, 5), st.integers(0, 10**6),
                                           st.text(max_size=300)), max_size=20),
                        min_size=1, max_size=8),
       cuts=st.lists(st.integers(0, 10**5), max_size=12))
def test_the_channel_hands_over_each_frame_whole_however_the_bytes_arrive(
        batches: list[list[Op]], cuts: list[int]) -> None:
    frames = [frame(ops) for ops in batches]
    stream = b"".join(frames)
    ends = list(itertools.accumulate(len(f) for f in frames))
    bounds = sorted({c % (len(stream) + 1) for c in cuts} | {0, len(stream)})

    async def go() -> list[list[Op]]:
        got: list[list[Op]] = []
        channel = Channel(lambda payload: got.append(batch_of(payload)))
        for a, b in itertools.pairwise(bounds):
            channel.data_received(stream[a:b])
            assert len(got) == sum(end <= b for end in ends)  # each frame once it is whole
        return got

    assert asyncio.run(go()) == batches
