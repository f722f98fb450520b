"""Kobuki driver against a real pseudo-terminal; the test plays the base."""

from __future__ import annotations

import os
import time
from collections.abc import Iterator

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from robot_client.kobuki import (
    BUMPER_CENTRAL,
    BUMPER_LEFT,
    RADIUS_SPIN,
    RADIUS_STRAIGHT,
    BasicSensorData,
    KobukiError,
    KobukiSerial,
    PacketParser,
    base_control,
    sound,
    sound_sequence,
    twist_to_base_control,
    wheel_speeds,
)
from tests.robot_client.kobuki_side import basic_sensor_payload, frame, read_commands


@pytest.fixture
def pty_base() -> Iterator[tuple[int, KobukiSerial]]:
    """(pty master held by the test, driver opened on the slave's path)."""
    master, slave = os.openpty()
    driver = KobukiSerial(os.ttyname(slave))
    yield master, driver
    driver.close()
    os.close(slave)
    os.close(master)


def poll_until(driver: KobukiSerial, count: int, timeout_s: float = 2.0) -> list[BasicSensorData]:
    """Poll the driver until ``count`` feedback packets arrived (or the timeout)."""
    got: list[BasicSensorData] = []
    end = time.monotonic() + timeout_s
    while len(got) < count and time.monotonic() < end:
        got += driver.poll()
        time.sleep(0.002)
    return got


def test_command_packets_match_hand_encoded_bytes() -> None:
    # Payload = id, size, data; length = 6 for base control; checksum = XOR(length..payload):
    # 06^01^04^64^00^00^00^00 = 0x67.
    assert base_control(100, 0) == bytes.fromhex("aa55 06 0104 6400 0000 67".replace(" ", ""))
    # speed -200 = 0xff38 LE "38ff", radius 1 "0100": 06^01^04^38^ff^01^00 = 0xc5.
    assert base_control(-200, 1) == bytes.fromhex("aa55060104" "38ff" "0100" "c5")
    # 440 Hz: note = round(1/(440*0.00000275)) = 826 = 0x033a; 100 ms = 0x64;
    # 05^03^03^3a^03^64 = 0x58.
    assert sound(440, 100) == bytes.fromhex("aa5505" "0303" "3a0364" "58")
    assert sound_sequence(2) == bytes.fromhex("aa5503" "040102" "04")  # 03^04^01^02 = 0x04


@pytest.mark.parametrize("bad", [lambda: base_control(40000, 0), lambda: base_control(0, -40000),
                                 lambda: sound(440, 0), lambda: sound(0.001, 10),
                                 lambda: sound_sequence(7)])
def test_out_of_range_commands_are_refused(bad: object) -> None:
    with pytest.raises(KobukiError):
        bad()  # type: ignore[operator]


def test_twist_conversion_round_trips_through_wheel_speeds() -> None:
    b = 0.230
    assert twist_to_base_control(0.2, 0.0, b) == (200, RADIUS_STRAIGHT)
    # Spin at 1 rad/s: each wheel at w * b / 2 = 115 mm/s.
    assert twist_to_base_control(0.0, 1.0, b) == (115, RADIUS_SPIN)
    assert wheel_speeds(115, RADIUS_SPIN, b) == (-115.0, 115.0)
    # v = 0.1 m/s, w = 0.2 rad/s: R = 500 mm, outer (right) wheel (500 + 115) * 0.2 = 123 mm/s,
    # inner 385 * 0.2 = 77 mm/s.
    assert twist_to_base_control(0.1, 0.2, b) == (123, 500)
    left, right = wheel_speeds(123, 500, b)
    assert left == pytest.approx(77.0) and right == pytest.approx(123.0)
    # Reversing on a clockwise arc (R = -500): outer wheel is the left one.
    speed, radius = twist_to_base_control(-0.1, 0.2, b)
    assert (speed, radius) == (-123, -500)
    left, right = wheel_speeds(speed, radius, b)
    assert left == pytest.approx(-123.0) and right == pytest.approx(-77.0)


def test_driver_decodes_feedback_from_pty(pty_base: tuple[int, KobukiSerial]) -> None:
    master, driver = pty_base
    os.write(master, frame(basic_sensor_payload(timestamp=65535, bumper=BUMPER_LEFT | 0x01,
                                                wheel_drop=2, cliff=4, left=12345, right=65535,
                                                buttons=1, battery_dv=152)))
    (data,) = poll_until(driver, 1)
    assert data == BasicSensorData(timestamp_ms=65535, bumper=5, wheel_drop=2, cliff=4,
                                   left_encoder=12345, right_encoder=65535, left_pwm=0,
                                   right_pwm=0, buttons=1, charger=0, battery_dv=152,
                                   overcurrent=0)
    assert data.bumped and data.battery_v == pytest.approx(15.2)
    assert driver.latest == data


def test_driver_resyncs_on_split_garbage_and_bad_checksums(
        pty_base: tuple[int, KobukiSerial]) -> None:
    master, driver = pty_base
    good = [frame(basic_sensor_payload(timestamp=t, left=t * 7, right=t * 11,
                                       bumper=BUMPER_CENTRAL if t == 3 else 0))
            for t in range(1, 6)]
    corrupted = bytearray(frame(basic_sensor_payload(timestamp=999)))
    corrupted[8] ^= 0xFF  # a payload byte flipped: checksum no longer matches
    # A false header with a length that claims the next valid packet's bytes.
    false_header = b"\xaa\x55\x10\x01"
    stream = (b"\x00\x13\xaa" + good[0] + bytes(corrupted) + good[1] + false_header + good[2]
              + b"\xaa\x55\x01\x00\x01" + good[3] + b"\xff\xaa" + good[4])
    for i in range(0, len(stream), 7):  # arrives in 7-byte pieces
        os.write(master, stream[i : i + 7])
        time.sleep(0.001)
    got = poll_until(driver, 5)
    assert [d.timestamp_ms for d in got] == [1, 2, 3, 4, 5]
    assert [d.left_encoder for d in got] == [7, 14, 21, 28, 35]
    assert [d.bumped for d in got] == [False, False, True, False, False]
    assert driver.parser.bad_checksums >= 1


def test_driver_writes_command_packets_to_pty(pty_base: tuple[int, KobukiSerial]) -> None:
    master, driver = pty_base
    raw = bytearray()
    driver.drive(150, RADIUS_STRAIGHT)
    driver.twist(0.0, -1.0)  # clockwise spin: speed -115 with the spin radius
    driver.send(sound(440, 100))
    driver.stop()
    assert read_commands(master, raw, min_count=3) == [(150, 0), (-115, 1), (0, 0)]


def test_unopenable_port_gives_a_clear_error() -> None:
    with pytest.raises(OSError, match="cannot open Kobuki serial port"):
        KobukiSerial("/nonexistent/ttyKOBUKI")


packets = st.lists(st.tuples(st.integers(0, 65535), st.integers(0, 65535), st.integers(0, 7)),
                   min_size=1, max_size=8)
noise = st.binary(max_size=12).map(lambda b: bytes(x for x in b if x != 0xAA))


@settings(max_examples=150, deadline=None)
@given(packets, st.lists(noise, min_size=9, max_size=9), st.lists(st.integers(1, 40),
                                                                   min_size=1, max_size=20))
def test_parser_recovers_every_packet_whatever_the_chunking_and_noise(
        fields: list[tuple[int, int, int]], gaps: list[bytes], cuts: list[int]) -> None:
    stream = b"".join(gaps[i % 9] + frame(basic_sensor_payload(timestamp=t, left=left,
                                                               bumper=bump))
                      for i, (t, left, bump) in enumerate(fields))
    parser, got, i, k = PacketParser(), [], 0, 0
    while i < len(stream):
        step = cuts[k % len(cuts)]
        got += [p.basic_sensor_data() for p in parser.feed(stream[i : i + step])]
        i, k = i + step, k + 1
    assert [(d.timestamp_ms, d.left_encoder, d.bumper) for d in got if d] == fields
