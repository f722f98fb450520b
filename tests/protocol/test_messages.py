"""Protocol v2 (serving v1 peers): every message type round-trips, the exported schema
accepts exactly them."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Literal

import jsonschema
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from gateway.cli import main
from protocol import (
    MAX_MESSAGE_BYTES,
    MESSAGE_TYPES,
    Action,
    AnyMessage,
    ErrorCode,
    Event,
    Finished,
    Pose,
    ProtocolError,
    action_id,
    decode,
    encode,
    encode_action,
    json_schema,
    parse_action_id,
)
from protocol.messages import EventKind
from tests.protocol.samples import samples

VALIDATOR = jsonschema.Draft202012Validator(json_schema())


def test_samples_cover_every_message_type() -> None:
    assert sorted(m.type for m in samples()) == sorted(MESSAGE_TYPES)


@pytest.mark.parametrize("message", samples(), ids=lambda m: m.type)
def test_every_message_round_trips_and_matches_the_schema(message: AnyMessage) -> None:
    text = encode(message)
    assert decode(text) == message
    assert decode(text.encode()) == message
    VALIDATOR.validate(json.loads(text))


@pytest.mark.parametrize("message", samples(), ids=lambda m: m.type)
def test_minimal_messages_round_trip(message: AnyMessage) -> None:
    # only the required fields (as listed by the exported schema) plus v/type/msg_id/seq
    schema = json_schema()["$defs"][type(message).__name__]
    full = json.loads(encode(message))
    minimal = {k: full[k] for k in schema["required"]}
    VALIDATOR.validate(minimal)
    assert decode(json.dumps(minimal)).type == message.type


@pytest.mark.parametrize("message", samples(), ids=lambda m: m.type)
def test_schema_rejects_extra_fields_and_other_versions(message: AnyMessage) -> None:
    data = json.loads(encode(message))
    assert not VALIDATOR.is_valid({**data, "surplus": 1})
    assert not VALIDATOR.is_valid({**data, "v": 4})
    assert VALIDATOR.is_valid({**data, "v": 1})  # v2 serves v1 peers
    without_v = {k: v for k, v in data.items() if k != "v"}
    assert not VALIDATOR.is_valid(without_v)
    with pytest.raises(ProtocolError) as err:
        decode(json.dumps({**data, "surplus": 1}))
    assert err.value.code is ErrorCode.INVALID and err.value.ref == data["msg_id"]


cells = st.tuples(st.integers(0, 10_000), st.integers(0, 10_000))
headings = st.none() | st.sampled_from(["E", "N", "W", "S"])
poses = st.builds(Pose, cell=cells, heading=headings)


@settings(max_examples=60, deadline=None)
@given(plan=st.integers(0, 10**6), robot=st.integers(0, 10**4), index=st.integers(0, 10**6),
       src=poses, dst=poses, seq=st.integers(0, 2**53),
       msg_id=st.text(min_size=1, max_size=64),
       duration=st.floats(min_value=1e-3, max_value=1e9, allow_nan=False),
       v=st.sampled_from([1, 2]))
def test_actions_round_trip(plan: int, robot: int, index: int, src: Pose, dst: Pose, seq: int,
                            msg_id: str, duration: float, v: Literal[1, 2]) -> None:
    aid = action_id(plan, robot, index)
    assert parse_action_id(aid) == (plan, robot, index)
    msg = Action(v=v, msg_id=msg_id, seq=seq, action_id=aid, sequence=index, src=src, dst=dst,
                 duration_ms=duration)
    text = encode(msg)
    assert decode(text) == msg
    VALIDATOR.validate(json.loads(text))
    # the gateway's hot path writes the same message without the model
    fast = encode_action(v, msg_id, seq, {
        "action_id": aid, "sequence": index, "src": src.model_dump(), "dst": dst.model_dump(),
        "duration_ms": duration})
    assert json.loads(fast) == json.loads(text)
    assert decode(fast) == msg


@settings(max_examples=40, deadline=None)
@given(kind=st.sampled_from(["dispatch", "start", "finish", "blocked", "unblocked", "cancel"]),
       t=st.floats(0, 1e9, allow_nan=False), plan=st.integers(0, 99), robot=st.integers(0, 999),
       action=st.integers(0, 999))
def test_trace_like_events_round_trip(kind: EventKind, t: float, plan: int, robot: int,
                                      action: int) -> None:
    msg = Event(msg_id="e", seq=0, event=kind, t_ms=t, plan=plan, robot=robot, action=action)
    assert decode(encode(msg)) == msg


def test_action_sequence_must_match_its_id() -> None:
    good = json.loads(encode(samples()[9]))
    with pytest.raises(ProtocolError) as err:
        decode(json.dumps({**good, "sequence": good["sequence"] + 1}))
    assert err.value.code is ErrorCode.INVALID


@pytest.mark.parametrize(
    ("raw", "code", "ref"),
    [
        ("{not json", ErrorCode.MALFORMED, None),
        ("[1, 2]", ErrorCode.MALFORMED, None),
        (b"\xff\xfe", ErrorCode.MALFORMED, None),
        ('{"v": 4, "type": "ack", "msg_id": "m1", "seq": 0}', ErrorCode.UNSUPPORTED_VERSION,
         "m1"),
        ('{"type": "ack", "msg_id": "m2", "seq": 0}', ErrorCode.UNSUPPORTED_VERSION, "m2"),
        ('{"v": 1, "type": "teleport", "msg_id": "m3", "seq": 0}', ErrorCode.UNKNOWN_TYPE, "m3"),
        ('{"v": 1, "msg_id": "m4", "seq": 0}', ErrorCode.UNKNOWN_TYPE, "m4"),
        ('{"v": 1, "type": "ack", "msg_id": "m5", "seq": 0}', ErrorCode.INVALID, "m5"),
        ('{"v": 1, "type": "ack", "msg_id": "m6", "seq": -1, "action_id": "0.0.0"}',
         ErrorCode.INVALID, "m6"),
        ('{"v": 1, "type": "ack", "msg_id": "m7", "seq": 0, "action_id": "zero"}',
         ErrorCode.INVALID, "m7"),
        ("x" * (MAX_MESSAGE_BYTES + 1), ErrorCode.TOO_LARGE, None),
    ],
)
def test_bad_input_gets_its_code(raw: str | bytes, code: ErrorCode, ref: str | None) -> None:
    with pytest.raises(ProtocolError) as err:
        decode(raw)
    assert err.value.code is code
    assert err.value.ref == ref


def test_parse_action_id_refuses_garbage() -> None:
    with pytest.raises(ValueError, match="not an action id"):
        parse_action_id("1.2")


def test_finished_pose_is_optional() -> None:
    assert decode('{"v":1,"type":"finished","msg_id":"a","seq":3,"action_id":"0.1.2"}') == \
        Finished(v=1, msg_id="a", seq=3, action_id="0.1.2")


def test_cli_writes_the_schema(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "schema.json"
    assert main(["protocol", "schema", "-o", str(out)]) == 0
    assert json.loads(out.read_text()) == json.loads(json.dumps(json_schema()))
    assert main(["protocol", "schema"]) == 0
    assert json.loads(capsys.readouterr().out) == json.loads(out.read_text())
    assert main(["protocol", "schema", "-o", str(tmp_path / "no" / "such.json")]) == 2
    assert "cannot write" in capsys.readouterr().err
