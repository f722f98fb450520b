"""What a new operator met in the GUI's first hour (issue 27 items 2, 7, 8, 9), in headless
Chromium against real gateways: ``fleetgate demo`` as ``scripts/demo.sh`` runs it, a lifelong
demo, and an empty shift of ``fleetgate serve``."""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
import time
import urllib.request
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any
from urllib.parse import urlsplit

import pytest
from playwright.sync_api import Browser, Page, expect
from playwright.sync_api import TimeoutError as PlaywrightTimeout

from fleetgate.userio import children
from tests.gui.conftest import ARTIFACTS
from tests.gui.demo_process import DemoProcess

pytestmark = pytest.mark.gui

DANGER = "rgb(224, 49, 49)"
"""The colour of errors (style.css --danger)."""


@contextmanager
def gui(browser: Browser, url: str, name: str) -> Iterator[tuple[Page, list[str]]]:
    """The GUI at ``url`` in a fresh page, with the path and query of every request it made
    (fails on any uncaught JavaScript error; screenshot to test-artifacts/gui/)."""
    context = browser.new_context(viewport={"width": 1280, "height": 1000})
    page = context.new_page()
    errors: list[str] = []
    requests: list[str] = []
    page.on("pageerror", lambda exc: errors.append(str(exc)))
    page.on("request", lambda r: requests.append(
        urlsplit(r.url).path + ("?" + urlsplit(r.url).query if urlsplit(r.url).query else "")))
    page.goto(url)
    page.wait_for_function("window.fleetgate && window.fleetgate.model.snap !== null")
    try:
        yield page, requests
    finally:
        ARTIFACTS.mkdir(parents=True, exist_ok=True)
        page.screenshot(path=str(ARTIFACTS / f"{name}.png"), full_page=True)
        context.close()
    assert not errors, f"JavaScript errors on the page: {errors}"


def task_requests(requests: list[str]) -> list[str]:
    """The task API requests among ``requests`` (not the page's tasks.js)."""
    return [r for r in requests if re.match(r"^/tasks(/|\?|$)", r)]


def health(url: str) -> dict[str, Any]:
    """The gateway's /healthz (no login needed)."""
    parts = urlsplit(url)
    opener = urllib.request.build_opener(urllib.request.ProxyHandler({}))
    with opener.open(f"http://{parts.netloc}/healthz", timeout=5) as resp:
        body: dict[str, Any] = json.load(resp)
    return body


def api(page: Page, path: str) -> Any:
    """GET a task API path with the page's login."""
    return page.evaluate("async p => (await fetch(p, {credentials: 'same-origin'})).json()",
                         path)


def wait_for_replan(page: Page, demo: DemoProcess, timeout_ms: float) -> None:
    """Waits until the GUI shows the run's first replan; on a timeout the failure names what
    the GUI's log and the demo's own output said."""
    try:
        page.wait_for_function("window.fleetgate.plan() === 1", timeout=timeout_ms)
    except PlaywrightTimeout:
        raise AssertionError("no replan shown; the GUI's log:\n"
                             + page.locator("#log").inner_text()[-2000:]
                             + "\nthe demo's output:\n" + "".join(demo.lines[-30:])) from None


def test_the_demo_starts_when_its_gui_is_first_opened(browser: Browser) -> None:
    """Item 9: nobody watching, nothing runs (on main the intruder came and went at 3-10 s of
    plan time, 0.75-2.5 s of wall time at speed 4); the first login starts the run, and the
    viewer sees the intruder, the trigger and the replan. Item 8: no task API requests. The
    demo runs in virtual time paced by the wall clock (``--virtual-time``): in real time a
    starved demo let the intruder leave before the slack crossed the threshold."""
    with DemoProcess("--speed", "4", "--virtual-time") as demo:
        deadline = time.monotonic() + 30
        while health(demo.url)["robots"] < 10 and time.monotonic() < deadline:
            time.sleep(0.1)  # every robot connected: on main the run starts now
        time.sleep(3.0)  # 12 s of plan time
        before = health(demo.url)
        assert (before["gateway"], before["robots"]) == ("loaded", 10), before
        with gui(browser, demo.url, "first-hour-demo-start") as (page, requests):
            expect(page.locator("#status")).to_have_text("running", timeout=10_000)
            page.wait_for_function("window.fleetgate.model.snap.intruders.length > 0",
                                   timeout=10_000)
            wait_for_replan(page, demo, 20_000)
            expect(page.locator("#log")).to_contain_text("replan triggered")
            assert task_requests(requests) == []


def test_a_rerun_from_the_gui_brings_the_intruder_again(browser: Browser) -> None:
    """Item 9: whoever presses Start again after the first run sees the intruder and the
    replan again (on main the automatic intruder came in the first run only). In virtual time
    paced by the wall clock, as above."""
    with DemoProcess("--speed", "5", "--start", "now", "--virtual-time") as demo, \
            gui(browser, demo.url, "first-hour-rerun") as (page, _):
        page.wait_for_function("window.fleetgate.status() === 'done'", timeout=60_000)
        page.get_by_role("button", name="Start").click()
        expect(page.locator("#status")).to_have_text("running", timeout=10_000)
        page.wait_for_function("window.fleetgate.model.snap.intruders.length > 0",
                               timeout=15_000)
        wait_for_replan(page, demo, 20_000)
        page.wait_for_function("window.fleetgate.status() === 'done'", timeout=60_000)


def test_the_demo_instance_form_shows_its_map_and_scenario_and_loads_them(
        browser: Browser) -> None:
    """Item 2: the form shows the demo's map and scenario (not the scenario as the map), Load
    loads them again; a refusal names no server path. Item 8: a one-shot gateway's page never
    asks the task API (on main it polled /tasks for a 503 every 10 s)."""
    with DemoProcess("--speed", "10", "--no-intruder", "--start", "now") as demo, \
            gui(browser, demo.url, "first-hour-instance") as (page, requests):
        expect(page.get_by_label("Map", exact=True)).to_have_value("lab")
        expect(page.get_by_label("Scenario", exact=True)).to_have_value("lab-random-4")
        expect(page.get_by_label("Robots", exact=True)).to_have_value("10")
        expect(page.locator("#map-now")).to_have_text("lab · 10 robots")
        page.wait_for_function("window.fleetgate.status() === 'done'", timeout=30_000)
        page.get_by_role("button", name="Load").click()
        expect(page.locator("#notice")).to_contain_text("loaded lab: 10 robots", timeout=15_000)
        expect(page.locator("#status")).to_have_text("loaded")
        expect(page.locator("#load-note")).to_have_text("")
        page.get_by_label("Map", exact=True).fill("lab-random-4")
        page.get_by_role("button", name="Load").click()
        note = page.locator("#load-note")
        expect(note).to_contain_text("no map named 'lab-random-4' on the gateway")
        assert "/" not in (note.text_content() or "")
        assert task_requests(requests) == []


@pytest.fixture(scope="module")
def shift() -> Iterator[DemoProcess]:
    """A lifelong demo: 20 robots in the generated warehouse, the task list streaming in."""
    with DemoProcess("--lifelong", "--robots", "20", "--speed", "4") as proc:
        yield proc


def test_the_lifelong_gui_shows_the_shift_and_offers_what_the_gateway_accepts(
        browser: Browser, shift: DemoProcess) -> None:
    """Item 7: the Instance card, the top bar, the Execution, Messages and task cards show
    the shift; controls the gateway would refuse are off; one rate with the terminal. Item
    8: no ``after=Infinity`` (a second timer for an id already missing)."""
    with gui(browser, shift.url, "first-hour-shift") as (page, requests):
        expect(page.locator("#tasks-card")).to_be_visible(timeout=20_000)
        expect(page.get_by_label("Map", exact=True)).to_have_value("warehouse")
        expect(page.get_by_label("Robots", exact=True)).to_have_value("20")
        expect(page.get_by_label("Map", exact=True)).to_be_disabled()
        expect(page.get_by_role("button", name="Load")).to_be_disabled()
        expect(page.locator("#instance-hint")).to_be_visible()
        # the lifelong demo has no simulated world: the gateway would refuse an intruder
        expect(page.get_by_role("button", name="Place intruder")).to_be_disabled()
        expect(page.get_by_label("Policy")).to_be_disabled()
        expect(page.locator("#policy-now")).to_have_text(
            "window every 1.0 s, early at slack > 2.0 s")
        expect(page.locator("#exec-costs")).to_be_hidden()
        expect(page.locator("#log")).to_contain_text("lifelong shift on warehouse: 20 robots")
        expect(page.locator("#robot-rows tr")).to_have_count(20)  # the Robots card
        counts = page.locator("#tasks-counts")
        expect(counts).to_contain_text("robots at work")
        assert counts.evaluate("e => getComputedStyle(e).color") != DANGER
        page.wait_for_function("window.fleetgate.tasks.finished >= 3", timeout=60_000)
        expect(page.locator("#log")).to_contain_text("finished by robot")
        # one rate: the gateway's tasks per minute of the shift, as the terminal prints it
        # (throughput_per_min), read with the snapshot it came in: the shift runs on in real
        # time, so a later listing's rate differs (9.8 shown, 11.8 two seconds later, with a
        # second suite on the same cores)
        page.wait_for_timeout(2500)  # a snapshot or two after the last finish
        shown, t_ms, per_min = page.evaluate(
            "() => [document.getElementById('tasks-rate').textContent,"
            " window.fleetgate.model.snap.t_ms, window.fleetgate.model.snap.tasks_per_min]")
        assert shown == f"{per_min:.1f} / min", (shown, per_min)
        finished = per_min * t_ms / 60_000.0  # tasks finished by then: a whole number
        assert finished >= 1 and abs(finished - round(finished)) < 1e-6, (per_min, t_ms)
        listing = api(page, "/tasks?limit=1")  # later: as many finished or more
        assert round(finished) <= listing["counts"]["finished"] and t_ms <= listing["now_ms"]
        # each robot once in "Robots at work", and the count says robots
        rows = page.locator("#work-rows tr")
        robots = [int(r) for r in rows.evaluate_all("rs => rs.map(r => r.cells[0].textContent)")]
        assert len(robots) == len(set(robots)) and len(robots) <= 20
        assert re.search(r"\b(\d+) robots at work", counts.text_content() or "")
        assert "Infinity" not in " ".join(task_requests(requests))
        assert all("after=" not in r or re.search(r"after=-?\d+(&|$)", r)
                   for r in task_requests(requests)), task_requests(requests)


def test_an_empty_shift_says_where_tasks_come_from_and_takes_one_from_the_gui(
        browser: Browser, tmp_path: Path) -> None:
    """Item 7: a shift without tasks points to POST /tasks and the GUI adds one (a task
    submitted before the shift starts is at 0 of the shift's clock, item 5)."""
    config = tmp_path / "gw.toml"
    config.write_text('port = 0\nlog_level = "WARNING"\n\n[lifelong]\nrobots = 3\n'
                      "task_list = false\n")
    env = {k: v for k, v in os.environ.items()
           if "proxy" not in k.lower() and not k.startswith("FLEETGATE_")}
    proc = subprocess.Popen([sys.executable, "-m", "gateway", "serve", "--config", str(config),
                             "--no-journal"], stderr=subprocess.PIPE, text=True, env=env)
    try:
        assert proc.stderr is not None
        line = proc.stderr.readline()
        m = re.search(r"ws://127\.0\.0\.1:(\d+)/", line)
        assert m, line
        url = f"http://127.0.0.1:{m[1]}/login#token=demo-operator"
        with gui(browser, url, "first-hour-empty-shift") as (page, _):
            expect(page.locator("#tasks-card")).to_be_visible(timeout=20_000)
            hint = page.locator("#tasks-empty")
            expect(hint).to_be_visible()
            expect(hint).to_contain_text("POST /tasks")
            rows = page.evaluate("window.fleetgate.model.snap.rows")
            free = [(x, y) for y, row in enumerate(rows) for x, c in enumerate(row) if c == "."]
            (x1, y1), (x2, y2) = free[0], free[-1]
            page.get_by_label("Errands").fill(f"{x1},{y1} {x2},{y2}")
            page.get_by_label("Priority").fill("5")
            page.get_by_role("button", name="Add task").click()
            note = page.locator("#tasks-note")
            expect(note).to_have_text(re.compile(r"^task \d+: added$"))
            task_id = int((note.text_content() or "").split()[1].rstrip(":"))
            expect(page.locator(f"#queue-rows tr[data-task='{task_id}']")).to_be_visible()
            expect(hint).to_be_hidden()
            task = api(page, f"/tasks/{task_id}")
            assert task["errands"] == [[x1, y1], [x2, y2]] and task["priority"] == 5
            assert task["state"] == "queued" and task["submitted_ms"] == 0.0
            page.get_by_label("Errands").fill(f"{x1},{y1} 99999,0")
            page.get_by_role("button", name="Add task").click()
            expect(note).to_contain_text("is not a free cell")
    finally:
        children.stop(proc, grace_s=20.0)  # SIGTERM: the demo stops cleanly on it
