"""Turning robots in the GUI (headless Chromium on a real ``fleetgate demo``): a turning plan
loaded over the operator websocket draws each robot's heading as a wedge, rotates a robot
while it turns, and the canvas pixels show the wedge where the heading points."""

from __future__ import annotations

import json
import math
from urllib.parse import urlsplit

from playwright.sync_api import Page
from websockets.sync.client import connect

from protocol import LoadPlan, SetSpeed, Start, decode, encode
from tests.gui.demo_process import DemoProcess

# robot 0 drives east, turns south, drives on; robot 1 turns twice (east -> south -> west)
PATHS = [[(0, 0), (1, 0), (1, 0), (1, 1)], [(5, 1), (5, 1), (5, 1), (4, 1)]]
HEADINGS = [[0, 0, 1, 1], [0, 1, 2, 2]]


def _command(demo: DemoProcess, *messages: object) -> None:
    """Send operator commands over a websocket; each must be answered ``ok``."""
    parts = urlsplit(demo.url)  # http://HOST:PORT/login#token=OPERATOR-TOKEN (or no token)
    token = parts.fragment.removeprefix("token=") or "demo-operator"
    with connect(f"ws://{parts.netloc}/ws", additional_headers={"Authorization":
                                                               f"Bearer {token}"},
                 proxy=None) as ws:
        for m in messages:
            ws.send(encode(m))  # type: ignore[arg-type]
            ref = getattr(m, "msg_id", None)
            while True:
                reply = decode(ws.recv(timeout=10))
                if reply.type in ("ok", "error") and getattr(reply, "ref", None) == ref:
                    assert reply.type == "ok", reply
                    break


def _pixel(page: Page, x: float, y: float) -> list[int]:
    return page.evaluate(
        """([x, y]) => { const c = document.getElementById('map');
        const d = window.devicePixelRatio || 1;
        return Array.from(c.getContext('2d').getImageData(Math.round(x * d),
                                                           Math.round(y * d), 1, 1).data); }""",
        [x, y])


def test_turning_robots_draw_and_rotate_their_headings(page: Page, demo: DemoProcess) -> None:
    page.wait_for_function("['loaded', 'done', 'empty'].includes(window.fleetgate.status())",
                           timeout=30_000)
    _command(demo, LoadPlan(msg_id="t1", seq=0, map="lab", paths=PATHS, headings=HEADINGS),
             SetSpeed(msg_id="t2", seq=1, speed=1.0))
    page.wait_for_function("window.fleetgate.model.snap.headings.length === 2")
    before = {r["id"]: r for r in page.evaluate("window.fleetgate.robots()")}
    assert (before[0]["heading"], before[1]["heading"]) == ("E", "E")
    _command(demo, Start(msg_id="t3", seq=2))
    # robot 1's first action is a clockwise turn east -> south: seen part of the way
    page.wait_for_function("window.fleetgate.robots().some(r => r.id === 1 && r.turning"
                           " && r.angle > 0.05 && r.angle < 1.5)", timeout=10_000)
    page.wait_for_function("window.fleetgate.status() === 'done'", timeout=20_000)
    page.wait_for_timeout(300)  # a frame or two after the last event
    robots = {r["id"]: r for r in page.evaluate("window.fleetgate.robots()")}
    assert (robots[0]["heading"], robots[1]["heading"]) == ("S", "W")
    drawn = {d["id"]: d for d in page.evaluate("window.fleetgate.drawn()")}
    for rid, angle in ((0, math.pi / 2), (1, math.pi)):
        d = drawn[rid]
        assert abs(d["angle"] - angle) < 1e-9 and not d["turning"]
        ahead = _pixel(page, d["x"] + math.cos(angle) * d["rad"] * 0.8,
                       d["y"] + math.sin(angle) * d["rad"] * 0.8)
        behind = _pixel(page, d["x"] - math.cos(angle) * d["rad"] * 0.8,
                        d["y"] - math.sin(angle) * d["rad"] * 0.8)
        assert ahead[:3] == [255, 255, 255], ahead  # the white wedge points the way it faces
        assert behind[:3] != [255, 255, 255], behind  # the robot's colour on the other side
    assert json.loads(json.dumps(page.evaluate("window.fleetgate.model.snap.headings"))) == \
        HEADINGS
