"""The Kobuki's side of a real pseudo-terminal, written independently of robot_client.kobuki.

Tests play the base: they write feedback packets into the pty master and read the command
packets the driver wrote on the slave. Packets are built here with struct and XOR by hand so
that the driver's framing is checked against a separate implementation.
"""

from __future__ import annotations

import asyncio
import math
import os
import select
import struct
from dataclasses import dataclass
from functools import reduce
from operator import xor

TICKS_PER_REV = 2578.33
WHEEL_RADIUS_M = 0.035
WHEELBASE_M = 0.230


def frame(payload: bytes) -> bytes:
    """0xAA 0x55, length, payload, XOR of length and payload."""
    body = bytes((len(payload),)) + payload
    return b"\xaa\x55" + body + bytes((reduce(xor, body, 0),))


def basic_sensor_payload(*, timestamp: int = 0, bumper: int = 0, wheel_drop: int = 0,
                         cliff: int = 0, left: int = 0, right: int = 0, buttons: int = 0,
                         battery_dv: int = 160) -> bytes:
    """Sub-payload 1 (15 data bytes) with PWM, charger and over-current left at 0."""
    data = struct.pack("<HBBBHHbbBBBB", timestamp & 0xFFFF, bumper, wheel_drop, cliff,
                       left & 0xFFFF, right & 0xFFFF, 0, 0, buttons, 0, battery_dv, 0)
    return bytes((1, len(data))) + data


def read_commands(master: int, raw: bytearray, timeout_s: float = 1.0,
                  min_count: int = 1) -> list[tuple[int, int]]:
    """Read base control commands (speed, radius) from the master until ``min_count`` arrived.

    ``raw`` keeps the unparsed bytes between calls (commands may arrive split).
    """
    out: list[tuple[int, int]] = []
    while len(out) < min_count:
        ready, _, _ = select.select([master], [], [], timeout_s)
        if not ready:
            break
        raw += os.read(master, 4096)
        while len(raw) >= 3 and len(raw) >= 4 + raw[2]:
            assert raw[:2] == b"\xaa\x55", f"no header at {raw.hex()}"
            n = raw[2]
            pkt, rest = bytes(raw[: 4 + n]), raw[4 + n :]
            assert reduce(xor, pkt[2:], 0) == 0, f"bad checksum in {pkt.hex()}"
            if pkt[3] == 1:
                out.append(struct.unpack("<hh", pkt[5:9]))
            raw[:] = rest
    return out


@dataclass
class SimulatedBase:
    """Motor side of a Kobuki: integrates the commanded wheel speeds into encoder ticks.

    It knows the firmware's reading of (speed, radius): radius 0 straight, 1 spin in place,
    otherwise the outer wheel runs at ``speed`` on an arc of that radius. It also keeps the
    true pose (x, y, theta), integrated with small Euler steps, as the oracle.
    """

    x: float = 0.0
    y: float = 0.0
    theta: float = 0.0
    left_ticks: float = 1000.0
    right_ticks: float = 65000.0
    timestamp: int = 0
    command: tuple[int, int] = (0, 0)
    bumper: int = 0

    def wheel_speeds(self) -> tuple[float, float]:
        """(left, right) in m/s for the current command."""
        speed, radius = self.command
        s, half = speed / 1000.0, WHEELBASE_M / 2
        if radius == 0:
            return s, s
        if radius == 1:
            return -s, s
        r = radius / 1000.0
        w = s / (r + half) if r > 0 else s / (r - half)
        return w * (r - half), w * (r + half)

    def advance(self, dt_s: float) -> None:
        """Run the wheels for ``dt_s`` seconds."""
        vl, vr = self.wheel_speeds()
        steps = 20
        h = dt_s / steps
        for _ in range(steps):
            v, w = (vl + vr) / 2, (vr - vl) / WHEELBASE_M
            self.x += v * math.cos(self.theta) * h
            self.y += v * math.sin(self.theta) * h
            self.theta += w * h
        per_m = TICKS_PER_REV / (2 * math.pi * WHEEL_RADIUS_M)
        self.left_ticks += vl * dt_s * per_m
        self.right_ticks += vr * dt_s * per_m
        self.timestamp += round(dt_s * 1000)

    def feedback(self) -> bytes:
        """The feedback packet the base would send now."""
        return frame(basic_sensor_payload(
            timestamp=self.timestamp, bumper=self.bumper,
            left=round(self.left_ticks) % 65536, right=round(self.right_ticks) % 65536))


async def run_realtime(base: SimulatedBase, master: int, stop: asyncio.Event,
                       period_s: float = 0.02, max_step_s: float = 0.04) -> None:
    """Play the base in real time: every 20 ms advance, send feedback, take new commands.

    The base and the client share one event loop; when a loaded machine stalls it, the base
    advances at most ``max_step_s`` per iteration (its clock slows down) rather than driving
    on blindly for the whole stall, which no controller tick could have corrected.
    """
    loop = asyncio.get_running_loop()
    last = loop.time()
    raw = bytearray()
    while not stop.is_set():
        await asyncio.sleep(period_s)
        now = loop.time()
        base.advance(min(now - last, max_step_s))
        last = now
        os.write(master, base.feedback())
        commands = read_commands(master, raw, timeout_s=0.0, min_count=1_000_000)
        if commands:
            base.command = commands[-1]
