"""Decoding and encoding of protocol messages, with precise, coded errors.

:func:`decode` checks, in this order, size, JSON, version, ``type`` and fields, so that every
refusal maps to one :class:`~protocol.messages.ErrorCode` and, when it can be read, the
offending ``msg_id``.
"""

from __future__ import annotations

import json
import math
import re
from typing import Any

import orjson
from pydantic import TypeAdapter, ValidationError

from protocol.messages import (
    MAX_MESSAGE_BYTES,
    SUPPORTED_VERSIONS,
    AnyMessage,
    ErrorCode,
    Message,
    OperatorCommand,
    RobotMessage,
    WorldMessage,
)

MESSAGE_ADAPTER: TypeAdapter[AnyMessage] = TypeAdapter(Message)
"""Validates any protocol message (discriminated on ``type``)."""

MAX_DEPTH = 8
"""Deepest nesting of JSON arrays/objects in a message (``load_plan`` needs 4); deeper is
refused (``too_large``) before the frame is parsed."""

MAX_DIGITS = 32
"""Longest run of digits in a JSON number; longer is refused (``too_large``) before parsing."""

_LONG_NUMBER = re.compile(f"[0-9]{{{MAX_DIGITS + 1},}}")
_JSON_STRING = re.compile(r'"(?:[^"\\]|\\.)*"')
_NOT_BRACKET = re.compile(r"[^\[\]{}]")
_SURROGATE_ESCAPE = re.compile(r"\\u[dD][89a-fA-F]")

def _types(union: Any) -> frozenset[str]:
    members = getattr(union, "__args__", (union,))
    return frozenset(str(t.model_fields["type"].default) for t in members)


MESSAGE_TYPES: frozenset[str] = _types(AnyMessage)
"""Every value of ``type`` that the protocol defines."""

ROBOT_TYPES: frozenset[str] = _types(RobotMessage)
"""The types a robot may send."""

OPERATOR_TYPES: frozenset[str] = _types(OperatorCommand)
"""The types an operator may send."""

WORLD_TYPES: frozenset[str] = _types(WorldMessage)
"""The types the world connection may send."""


class ProtocolError(ValueError):
    """A message that cannot be accepted: ``code`` says why, ``ref`` is its msg_id if known."""

    def __init__(self, code: ErrorCode, detail: str, ref: str | None = None) -> None:
        super().__init__(f"{code.value}: {detail}")
        self.code = code
        self.detail = detail
        self.ref = ref


BINARY_FRAME = "binary frame: protocol v1 messages are JSON in websocket text frames"
"""Detail of the ``malformed`` error a binary frame gets (the protocol is text only)."""


def _first_error(exc: ValidationError) -> str:
    err = exc.errors(include_url=False)[0]
    where = ".".join(str(p) for p in err["loc"])
    return f"{where}: {err['msg']}" if where else str(err["msg"])


def _size(text: str) -> int:
    """Length of ``text`` in UTF-8 bytes (as it travels in a websocket frame)."""
    return len(text) if text.isascii() else len(text.encode("utf-8", "surrogatepass"))


def _check_shape(text: str) -> None:
    """Refuse nesting deeper than MAX_DEPTH and numbers longer than MAX_DIGITS without parsing
    (a parser would recurse or build huge integers first). Linear time, in C for small frames."""
    if text.count("[") + text.count("{") <= MAX_DEPTH and not _LONG_NUMBER.search(text):
        return
    bare = _JSON_STRING.sub('""', text)  # digits and brackets inside strings do not count
    if _LONG_NUMBER.search(bare):
        raise ProtocolError(ErrorCode.TOO_LARGE, f"a number has more than {MAX_DIGITS} digits")
    depth = deepest = 0
    for ch in _NOT_BRACKET.sub("", bare):
        depth += 1 if ch in "[{" else -1
        if depth > deepest:
            deepest = depth
            if deepest > MAX_DEPTH:
                raise ProtocolError(ErrorCode.TOO_LARGE, f"nested deeper than {MAX_DEPTH}")


def _has_surrogate(text: str) -> bool:
    try:
        text.encode("utf-8")
    except UnicodeEncodeError:
        return True
    return False


def _check_unicode(text: str) -> None:
    """Refuse lone surrogates (``"\\ud800"`` is valid JSON but no character: it could not be
    echoed back, logged or written to the trace as UTF-8)."""
    try:
        data = json.loads(text)
    except json.JSONDecodeError:
        return  # malformed: diagnosed later
    if _has_surrogate(json.dumps(data, ensure_ascii=False)) or _has_surrogate(text):
        raise ProtocolError(ErrorCode.MALFORMED, "a string holds a lone UTF-16 surrogate")


def check_text(text: str) -> None:
    """The limits :func:`decode` puts on any JSON text, for other JSON bodies (the task API):
    nesting, number length and lone surrogates; ProtocolError if one is broken."""
    _check_shape(text)
    if (("\\u" in text and _SURROGATE_ESCAPE.search(text))  # the substring test: 30x cheaper
            or (not text.isascii() and _has_surrogate(text))):
        _check_unicode(text)


def decode(raw: str | bytes) -> AnyMessage:
    """Parse one message; raise :class:`ProtocolError` with the matching code if it is bad.

    Bytes must be UTF-8 (the gateway itself refuses binary frames before decoding: see
    :data:`BINARY_FRAME`).
    """
    size = len(raw) if isinstance(raw, bytes) else _size(raw)
    if size > MAX_MESSAGE_BYTES:
        raise ProtocolError(ErrorCode.TOO_LARGE, f"{size} bytes > {MAX_MESSAGE_BYTES}")
    if isinstance(raw, bytes):
        try:
            raw = raw.decode("utf-8")
        except UnicodeDecodeError as exc:
            raise ProtocolError(ErrorCode.MALFORMED, f"not UTF-8: {exc}") from None
    check_text(raw)
    first: ValidationError | None = None
    try:  # fast path: parse and validate in one pass (pydantic-core), ~2x faster
        message = MESSAGE_ADAPTER.validate_json(raw, strict=True)
    except ValidationError as exc:
        first = exc
    else:
        if "v" in message.model_fields_set:  # ``v`` has a default but is mandatory on the wire
            return message
    try:
        data: Any = json.loads(raw)
    except json.JSONDecodeError as exc:
        raise ProtocolError(ErrorCode.MALFORMED, f"not JSON: {exc}") from None
    if not isinstance(data, dict):
        raise ProtocolError(ErrorCode.MALFORMED, "a message must be a JSON object")
    ref = data.get("msg_id") if isinstance(data.get("msg_id"), str) else None
    version = data.get("v")
    if type(version) is not int or version not in SUPPORTED_VERSIONS:
        raise ProtocolError(
            ErrorCode.UNSUPPORTED_VERSION,
            f"protocol version {version!r} not supported (this side speaks "
            f"{' and '.join(map(str, SUPPORTED_VERSIONS))})",
            ref,
        )
    kind = data.get("type")
    if not isinstance(kind, str) or kind not in MESSAGE_TYPES:
        raise ProtocolError(ErrorCode.UNKNOWN_TYPE, f"unknown message type {kind!r}", ref)
    detail = _first_error(first) if first is not None else "invalid"
    raise ProtocolError(ErrorCode.INVALID, f"{kind}: {detail}", ref)


def encode(message: AnyMessage) -> str:
    """The JSON text of a message (defaults included, so peers need no schema defaults)."""
    return message.model_dump_json()


def encode_action(v: int, msg_id: str, seq: int, fields: dict[str, Any]) -> str:
    """The JSON text of an ``action`` message with these envelope fields and ``fields`` (its
    own fields as plain JSON values: poses as ``{"cell": [x, y], "heading": h}``), written
    without building the model: the gateway's hot path, for the actions its own executor
    released. It decodes to the model that :func:`encode` of ``Action(...)`` gives."""
    return action_text(v, msg_id, seq, action_body(fields))


def action_body(fields: dict[str, Any]) -> str:
    """The JSON object of an action's own ``fields`` (orjson: ~5x cheaper than
    ``json.dumps``; it would write a NaN or infinite duration as ``null``, so such a duration
    is refused first, as ``allow_nan=False`` did). A worker process gets an action as this."""
    if not math.isfinite(fields["duration_ms"]):
        raise ValueError(f"duration_ms {fields['duration_ms']!r} is not a finite number")
    return orjson.dumps(fields).decode()


def action_text(v: int, msg_id: str, seq: int, body: str) -> str:
    """The ``action`` message of an :func:`action_body` with these envelope fields:
    ``encode_action``'s text. ``body`` must be what :func:`action_body` wrote, a JSON object
    that is never empty (it always holds ``duration_ms``): its opening brace is dropped and
    the envelope's fields go before the rest, with a comma."""
    return f'{{"v":{v},"msg_id":{orjson.dumps(msg_id).decode()},"seq":{seq},"type":"action",' \
        f'{body[1:]}'

