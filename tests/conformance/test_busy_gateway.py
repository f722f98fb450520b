"""`fleetgate conformance gateway` against a gateway at work (issue 27 item 6): a lifelong demo
whose shift is running with its simulated robots. The checker must see that first and exit 2
with one line, and no robot of the fleet may lose its connection meanwhile (an operator
watches the gateway's ``connection`` events the whole time)."""

from __future__ import annotations

import json
import re
import subprocess
import sys
import threading
import time
from urllib.parse import urlsplit

from websockets.sync.client import connect

from fleetgate.userio import children
from protocol import Event, decode


def test_a_busy_gateway_is_refused_in_one_line_touching_no_robot() -> None:
    demo = subprocess.Popen([sys.executable, "-m", "gateway", "demo", "--lifelong", "--robots",
                             "4", "--speed", "5", "--port", "0"],
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    try:
        assert demo.stderr is not None
        url = ""
        for line in demo.stderr:
            m = re.search(r"GUI at (http://\S+)", line)
            if m:
                url = m[1]
            if "shift started" in line:
                break
        assert url, "the lifelong demo did not start"
        parts = urlsplit(url)
        token = parts.fragment.removeprefix("token=")
        events: list[Event] = []
        watching = threading.Event()
        done = threading.Event()

        def watch() -> None:
            with connect(f"ws://{parts.netloc}/ws", proxy=None,
                         additional_headers={"Authorization": f"Bearer {token}"}) as ws:
                watching.set()
                while not done.is_set():
                    try:
                        msg = decode(ws.recv(timeout=0.2))
                    except TimeoutError:
                        continue
                    if isinstance(msg, Event):
                        events.append(msg)

        watcher = threading.Thread(target=watch, daemon=True)
        watcher.start()
        assert watching.wait(10)
        time.sleep(0.5)
        t0 = time.monotonic()
        check = subprocess.run(
            [sys.executable, "-m", "gateway", "conformance", "gateway",
             f"ws://{parts.netloc}/ws", "--token", "demo-robot-{id}", "--operator-token",
             token], capture_output=True, text=True, timeout=120)
        elapsed = time.monotonic() - t0
        time.sleep(1.0)  # a kicked robot would show as a connection event by now
        done.set()
        watcher.join(5)
        assert check.returncode == 2, (check.returncode, check.stdout, check.stderr)
        lines = check.stderr.strip().splitlines()
        assert len(lines) == 1 and "Traceback" not in check.stderr, check.stderr
        assert "busy (running, 4 robot(s) connected)" in lines[0], lines[0]
        assert check.stdout == ""
        assert elapsed < 30
        kicked = [e for e in events if e.event == "connection"]
        assert kicked == [], [json.loads(e.model_dump_json()) for e in kicked]
        assert any(e.event == "finish" for e in events)  # the watcher did hear the shift
        with connect(f"ws://{parts.netloc}/ws", proxy=None, additional_headers={
                "Authorization": f"Bearer {token}"}) as ws:
            snap = decode(ws.recv(timeout=10))
        assert getattr(snap, "status", None) == "running"
        assert all(r.connected for r in getattr(snap, "robots", []))
    finally:
        children.stop(demo, grace_s=20.0)  # SIGTERM: the demo stops cleanly on it
