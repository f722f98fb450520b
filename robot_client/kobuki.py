"""Kobuki (TurtleBot2 base) serial protocol: packet framing, commands, feedback, serial driver.

Written from Yujin Robot's published "Kobuki protocol specification". A packet is::

    0xAA 0x55 | length (1 byte) | payload (length bytes) | checksum (1 byte)

The payload is a sequence of sub-payloads ``id (1 byte) | size (1 byte) | data (size bytes)``;
multi-byte fields are little-endian. The checksum is the XOR of the length byte and every payload
byte (the two header bytes are excluded), so XOR-ing everything after the headers gives 0.

The same framing carries commands (host -> base) and feedback (base -> host, every 20 ms).
:class:`PacketParser` is sans-I/O: feed it whatever bytes arrived and it returns the complete,
valid packets, resynchronising on garbage, bad checksums and malformed payloads.
:class:`KobukiSerial` owns the serial port (pyserial; any tty path, pseudo-terminals included).
"""

from __future__ import annotations

import contextlib
import struct
from dataclasses import dataclass, field

import serial  # pyserial

HEADER = b"\xaa\x55"
MAX_PAYLOAD = 255

# Command sub-payload ids (host -> base).
CMD_BASE_CONTROL = 1
CMD_SOUND = 3
CMD_SOUND_SEQUENCE = 4

# Feedback sub-payload ids (base -> host).
FB_BASIC_SENSOR_DATA = 1
BASIC_SENSOR_DATA_SIZE = 15

# Base control special radii: 0 = drive straight, 1 = spin in place (speed > 0 turns
# counter-clockwise, each wheel moving at |speed|).
RADIUS_STRAIGHT = 0
RADIUS_SPIN = 1
INT16_MIN, INT16_MAX = -32768, 32767

# Sound note: the base takes 1 / (f * a) with a = 0.00000275 (spec).
SOUND_A = 0.00000275

# Bit flags of the basic sensor data.
BUMPER_RIGHT, BUMPER_CENTRAL, BUMPER_LEFT = 0x01, 0x02, 0x04
WHEEL_DROP_RIGHT, WHEEL_DROP_LEFT = 0x01, 0x02
CLIFF_RIGHT, CLIFF_CENTRAL, CLIFF_LEFT = 0x01, 0x02, 0x04
BUTTON_0, BUTTON_1, BUTTON_2 = 0x01, 0x02, 0x04

_BASIC = struct.Struct("<HBBBHHbbBBBB")


class KobukiError(ValueError):
    """A value that cannot be encoded in, or decoded from, the Kobuki protocol."""


def checksum(body: bytes) -> int:
    """XOR of ``body`` (the length byte followed by the payload)."""
    cs = 0
    for b in body:
        cs ^= b
    return cs


def sub_payload(sub_id: int, data: bytes) -> bytes:
    """One sub-payload: id, size, data."""
    if not 0 <= sub_id <= 255 or len(data) > 255:
        raise KobukiError(f"sub-payload id {sub_id} / size {len(data)} out of byte range")
    return bytes((sub_id, len(data))) + data


def encode_packet(payload: bytes) -> bytes:
    """Frame a payload (one or more sub-payloads) as a complete packet."""
    if not 0 < len(payload) <= MAX_PAYLOAD:
        raise KobukiError(f"payload length {len(payload)} not in 1..{MAX_PAYLOAD}")
    body = bytes((len(payload),)) + payload
    return HEADER + body + bytes((checksum(body),))


def base_control(speed_mm_s: int, radius_mm: int) -> bytes:
    """Base control command packet: ``speed`` in mm/s and ``radius`` in mm (both int16).

    Radius 0 drives straight; radius 1 spins in place (positive speed counter-clockwise);
    any other radius drives an arc whose outer wheel moves at ``speed`` (see :func:`wheel_speeds`).
    """
    for name, v in (("speed", speed_mm_s), ("radius", radius_mm)):
        if not INT16_MIN <= v <= INT16_MAX:
            raise KobukiError(f"{name} {v} does not fit in int16")
    return encode_packet(sub_payload(CMD_BASE_CONTROL, struct.pack("<hh", speed_mm_s, radius_mm)))


def sound(frequency_hz: float, duration_ms: int) -> bytes:
    """Sound command packet: play one note of ``frequency_hz`` for ``duration_ms`` (1..255)."""
    if frequency_hz <= 0:
        raise KobukiError(f"frequency {frequency_hz} must be positive")
    if not 0 < duration_ms <= 255:
        raise KobukiError(f"duration {duration_ms} ms not in 1..255")
    note = round(1.0 / (frequency_hz * SOUND_A))
    if not 0 < note <= 0xFFFF:
        raise KobukiError(f"frequency {frequency_hz} Hz is out of the base's range")
    return encode_packet(sub_payload(CMD_SOUND, struct.pack("<HB", note, duration_ms)))


def sound_sequence(number: int) -> bytes:
    """Sound sequence command packet: play built-in sequence 0..6 (on, off, recharge, ...)."""
    if not 0 <= number <= 6:
        raise KobukiError(f"sound sequence {number} not in 0..6")
    return encode_packet(sub_payload(CMD_SOUND_SEQUENCE, bytes((number,))))


def twist_to_base_control(v_m_s: float, w_rad_s: float, wheelbase_m: float) -> tuple[int, int]:
    """(speed mm/s, radius mm) that drive the base at linear ``v`` and angular ``w``.

    Straight when ``w`` is negligible or the radius would not fit in int16; spin in place when
    the radius is below 2 mm (speed = w * b / 2); otherwise an arc of radius v / w whose outer wheel
    moves at ``(|R| + b/2) * |w|`` with the sign of ``v``.
    """
    half_b_mm = wheelbase_m * 500.0
    v_mm = v_m_s * 1000.0
    if abs(w_rad_s) < 1e-6:
        return round(v_mm), RADIUS_STRAIGHT
    radius = v_mm / w_rad_s
    if abs(radius) < 2.0:
        return round(w_rad_s * half_b_mm), RADIUS_SPIN
    if abs(radius) > INT16_MAX:
        return round(v_mm), RADIUS_STRAIGHT
    outer = (abs(radius) + half_b_mm) * abs(w_rad_s)
    return round(outer if v_mm > 0 else -outer), round(radius)


def wheel_speeds(speed_mm_s: int, radius_mm: int, wheelbase_m: float) -> tuple[float, float]:
    """(left, right) wheel speeds in mm/s that the base runs for a base control command."""
    half_b_mm = wheelbase_m * 500.0
    if radius_mm == RADIUS_STRAIGHT:
        return float(speed_mm_s), float(speed_mm_s)
    if radius_mm == RADIUS_SPIN:
        return float(-speed_mm_s), float(speed_mm_s)
    # Outer wheel at |speed|: w = speed / (R + b/2) for R > 0, speed / (R - b/2) for R < 0.
    w = speed_mm_s / (radius_mm + half_b_mm) if radius_mm > 0 else speed_mm_s / (
        radius_mm - half_b_mm)
    return w * (radius_mm - half_b_mm), w * (radius_mm + half_b_mm)


@dataclass(frozen=True, slots=True)
class BasicSensorData:
    """Feedback sub-payload 1 (every 20 ms): the base's core sensors."""

    timestamp_ms: int
    bumper: int
    wheel_drop: int
    cliff: int
    left_encoder: int
    right_encoder: int
    left_pwm: int
    right_pwm: int
    buttons: int
    charger: int
    battery_dv: int
    """Battery voltage in units of 0.1 V."""
    overcurrent: int

    @staticmethod
    def decode(data: bytes) -> BasicSensorData:
        """Decode the 15 data bytes of a basic sensor data sub-payload."""
        if len(data) != BASIC_SENSOR_DATA_SIZE:
            raise KobukiError(f"basic sensor data has {len(data)} bytes, expected 15")
        return BasicSensorData(*_BASIC.unpack(data))

    @property
    def bumped(self) -> bool:
        """Any of the three bumpers is pressed."""
        return self.bumper != 0

    @property
    def battery_v(self) -> float:
        """Battery voltage in volts."""
        return self.battery_dv / 10.0


@dataclass(frozen=True, slots=True)
class Packet:
    """A valid packet: its sub-payloads as (id, data) pairs, in order."""

    subs: tuple[tuple[int, bytes], ...]

    def basic_sensor_data(self) -> BasicSensorData | None:
        """The packet's basic sensor data, if it carries one."""
        for sub_id, data in self.subs:
            if sub_id == FB_BASIC_SENSOR_DATA and len(data) == BASIC_SENSOR_DATA_SIZE:
                return BasicSensorData.decode(data)
        return None


def split_sub_payloads(payload: bytes) -> tuple[tuple[int, bytes], ...] | None:
    """The sub-payloads of ``payload``, or None if their sizes do not add up exactly."""
    subs: list[tuple[int, bytes]] = []
    i = 0
    while i < len(payload):
        if i + 2 > len(payload):
            return None
        sub_id, size = payload[i], payload[i + 1]
        end = i + 2 + size
        if end > len(payload):
            return None
        subs.append((sub_id, bytes(payload[i + 2 : end])))
        i = end
    return tuple(subs)


@dataclass
class PacketParser:
    """Sans-I/O packet finder: ``feed`` bytes, get complete valid packets back.

    Anything before a header is skipped. A candidate whose checksum or sub-payload sizes are
    wrong is rejected and the search resumes one byte after its header, so a stray 0xAA 0x55
    inside garbage or a corrupted packet never swallows the valid packets that follow.
    """

    buffer: bytearray = field(default_factory=bytearray)
    packets: int = 0
    bad_checksums: int = 0
    malformed: int = 0
    skipped_bytes: int = 0

    def feed(self, data: bytes) -> list[Packet]:
        """Add received bytes; return the packets completed by them."""
        self.buffer += data
        out: list[Packet] = []
        buf = self.buffer
        while True:
            start = buf.find(HEADER)
            if start < 0:
                # Keep a trailing 0xAA: it may be the first half of a header.
                keep = 1 if buf.endswith(HEADER[:1]) else 0
                self.skipped_bytes += len(buf) - keep
                del buf[: len(buf) - keep]
                break
            self.skipped_bytes += start
            del buf[:start]
            if len(buf) < 3:
                break
            length = buf[2]
            if length < 3:
                self._reject(counts_as_checksum=False)
                continue
            total = 3 + length + 1
            if len(buf) < total:
                break
            body = bytes(buf[2 : total - 1])
            if checksum(body) != buf[total - 1]:
                self._reject(counts_as_checksum=True)
                continue
            subs = split_sub_payloads(body[1:])
            if subs is None:
                self._reject(counts_as_checksum=False)
                continue
            del buf[:total]
            self.packets += 1
            out.append(Packet(subs))
        return out

    def _reject(self, *, counts_as_checksum: bool) -> None:
        """Drop the header byte of a bad candidate packet so the search resumes after it."""
        if counts_as_checksum:
            self.bad_checksums += 1
        else:
            self.malformed += 1
        self.skipped_bytes += 1
        del self.buffer[:1]


class KobukiSerial:
    """The Kobuki base on a serial port (115200 8N1): send commands, poll feedback.

    ``poll`` never blocks: it reads what has arrived and returns the basic sensor data of the
    packets completed so far, oldest first. ``latest`` is the most recent one.
    """

    BAUD = 115200

    def __init__(self, port: str, *, wheelbase_m: float = 0.230) -> None:
        try:
            self._serial = serial.Serial(port, self.BAUD, timeout=0, write_timeout=1.0)
        except (serial.SerialException, OSError) as exc:
            raise OSError(f"cannot open Kobuki serial port {port!r}: {exc}") from exc
        self.parser = PacketParser()
        self.wheelbase_m = wheelbase_m
        self.latest: BasicSensorData | None = None

    def fileno(self) -> int:
        """The port's file descriptor (for event loops that wait on readability)."""
        return int(self._serial.fileno())

    def poll(self) -> list[BasicSensorData]:
        """Read every byte available now; return the new basic sensor data packets."""
        waiting = self._serial.in_waiting
        data = self._serial.read(waiting) if waiting else b""
        out = [s for p in self.parser.feed(data) if (s := p.basic_sensor_data()) is not None]
        if out:
            self.latest = out[-1]
        return out

    def send(self, packet: bytes) -> None:
        """Write one encoded command packet."""
        self._serial.write(packet)
        self._serial.flush()

    def drive(self, speed_mm_s: int, radius_mm: int) -> None:
        """Send a base control command."""
        self.send(base_control(speed_mm_s, radius_mm))

    def twist(self, v_m_s: float, w_rad_s: float) -> None:
        """Drive at linear ``v`` (m/s) and angular ``w`` (rad/s, counter-clockwise positive)."""
        self.drive(*twist_to_base_control(v_m_s, w_rad_s, self.wheelbase_m))

    def stop(self) -> None:
        """Stop both wheels."""
        self.drive(0, RADIUS_STRAIGHT)

    def close(self) -> None:
        """Stop the base (best effort) and close the port."""
        with contextlib.suppress(serial.SerialException, OSError):
            self.stop()
        self._serial.close()
