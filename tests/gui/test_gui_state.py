"""The GUI shows only the world it was given and only offers what the gateway accepts:
robots on the new instance's starts after Load, Replan now off once the replan budget is
used, refusals next to the control, the true slack during a pause and no replan on resume
for a block that cleared meanwhile, a clock that stops with the run, and a wrong token that
says so (and stops retrying). Headless Chromium against a real ``fleetgate demo``."""

from __future__ import annotations

import time

import pytest
from playwright.sync_api import Page, expect

from tests.gui.conftest import SPEED
from tests.gui.demo_process import DemoProcess
from tests.gui.gui_page import cells, intruder_target, place_intruder, robots, set_speed
from tests.gui.test_gui import ACTIVE, INTRUDER_S, fresh_run

pytestmark = pytest.mark.gui


def finish_run(page: Page) -> None:
    """Run the current run to its end quickly (speed 20), then back to the test speed."""
    set_speed(page, 20)
    page.wait_for_function("window.fleetgate.status() === 'done'", timeout=30_000)
    set_speed(page, SPEED)


def test_load_draws_the_new_instance_only(page: Page) -> None:
    """After a run on lab, Load warehouse-small: every robot is drawn on its start cell of
    the new plan (all free cells of the new map), with its path ahead starting there."""
    fresh_run(page)
    finish_run(page)
    page.get_by_label("Map", exact=True).fill("warehouse-small")
    page.get_by_label("Scenario", exact=True).fill("warehouse-small-random-1")
    page.get_by_label("Robots", exact=True).fill("8")
    page.get_by_role("button", name="Load").click()
    page.wait_for_function("window.fleetgate.status() === 'loaded'"
                           " && window.fleetgate.robots().length === 8", timeout=30_000)
    snap = page.evaluate("window.fleetgate.model.snap")
    rows = snap["rows"]
    for r, path in zip(robots(page), snap["paths"], strict=True):
        x, y = r["cell"]
        assert [x, y] == path[0], r
        assert r["pos"] == [x, y]
        assert rows[y][x] == ".", f"robot {r['id']} drawn on a wall at {(x, y)}"
        assert r["remaining"][0] == [x, y]
    # a page opened now shows the loaded instance in its Instance form, not the page's defaults
    other = page.context.new_page()
    other.goto(page.url)
    other.wait_for_function("window.fleetgate && window.fleetgate.model.snap !== null")
    expect(other.get_by_label("Map", exact=True)).to_have_value("warehouse-small")
    expect(other.get_by_label("Scenario", exact=True)).to_have_value("warehouse-small-random-1")
    expect(other.get_by_label("Robots", exact=True)).to_have_value("8")
    other.close()
    # back to the module's instance for whoever runs next
    page.get_by_label("Map", exact=True).fill("lab")
    page.get_by_label("Scenario", exact=True).fill("lab-random-1")
    page.get_by_label("Robots", exact=True).fill("10")
    page.get_by_role("button", name="Load").click()
    expect(page.locator("#status")).to_have_text("loaded", timeout=30_000)


def test_replan_now_is_off_once_the_budget_is_used(page: Page) -> None:
    """The demo allows one replan per run: after it, Replan now is disabled and says why."""
    fresh_run(page)
    button = page.get_by_role("button", name="Replan now")
    expect(button).to_be_enabled()
    button.click()
    expect(page.locator("#plan-now")).to_have_attribute("data-plan", "1", timeout=15_000)
    page.wait_for_function("window.fleetgate.status() === 'running'", timeout=10_000)
    expect(button).to_be_disabled()
    expect(button).to_have_attribute("title", "the run's replan budget is used (1 of 1)")
    finish_run(page)


def test_a_refusal_shows_next_to_its_control(page: Page) -> None:
    """A refused Load says why inside the Instance card, in view, not in the message log."""
    page.get_by_label("Map", exact=True).fill("no-such-map")
    page.get_by_role("button", name="Load").click()
    note = page.locator("#load-note")
    expect(note).to_contain_text("load refused: no map named 'no-such-map'")
    expect(note).to_be_in_viewport()
    card = page.get_by_role("region", name="Instance").bounding_box()
    box = note.bounding_box()
    assert card is not None and box is not None
    assert card["y"] <= box["y"] and box["y"] + box["height"] <= card["y"] + card["height"]
    expect(page.locator("#notice")).not_to_contain_text("refused")
    page.get_by_label("Map", exact=True).fill("lab")


def test_the_clock_stops_with_the_run(page: Page) -> None:
    """Once the run is done the clock shows its end (the makespan, give or take the last
    report) and stays there; so does the slack chart's time axis."""
    fresh_run(page)
    finish_run(page)
    page.wait_for_function("window.fleetgate.model.snap.makespan_ms > 0")
    first = page.evaluate("window.fleetgate.clock()")
    shown = page.locator("#clock").inner_text()
    time.sleep(1.5)
    assert page.evaluate("window.fleetgate.clock()") == first
    assert page.locator("#clock").inner_text() == shown
    makespan = page.evaluate("window.fleetgate.model.snap.makespan_ms")
    assert makespan <= first < makespan + 1000


def test_pause_keeps_the_slack_live_and_a_cleared_block_does_not_replan(page: Page) -> None:
    """Slack policy (2 s), speed 1. An intruder blocks a robot; the operator pauses at once.
    While paused the monitor is still evaluated (the page's slack series goes on past the
    pause) and nothing replans; the intruder leaves during the pause; after Resume the run
    ends with plan 0 and no trigger: the waiting everyone did during the pause is not the
    fleet's delay. (The exact values are checked in tests/execution/test_pause.py.)"""
    page.get_by_label("Policy").select_option("slack")
    page.wait_for_function("window.fleetgate.model.snap.policy === 'slack'")
    try:
        if page.evaluate(ACTIVE):
            fresh_run(page)  # ends the run under way
            finish_run(page)
        set_speed(page, 1)  # slow enough that the robots are still far from the target
        page.get_by_role("button", name="Start").click()
        page.wait_for_function("window.fleetgate.status() === 'running'"
                               " && window.fleetgate.plan() === 0")
        place_intruder(page, intruder_target(page, INTRUDER_S), INTRUDER_S)
        page.wait_for_function(
            "window.fleetgate.robots().some(r => r.activity === 'blocked')", timeout=12_000)
        page.get_by_role("button", name="Pause").click()
        expect(page.locator("#status")).to_have_text("paused")
        paused_at = page.evaluate("window.fleetgate.model.snap.t_ms")
        page.wait_for_function(
            f"window.fleetgate.slack().some(p => p[0] >= {paused_at} + 1500)", timeout=10_000)
        assert page.evaluate("window.fleetgate.status()") == "paused"
        page.wait_for_function("window.fleetgate.model.snap.intruders.length === 0",
                               timeout=15_000)
        assert page.evaluate("window.fleetgate.plan()") == 0
        page.get_by_role("button", name="Resume").click()
        expect(page.locator("#status")).to_have_text("running")
        time.sleep(2.0)  # 2 s of plan time: the slack policy ticks 20 times meanwhile
        assert page.evaluate("window.fleetgate.plan()") == 0
        assert page.evaluate("window.fleetgate.model.marks") == []
    finally:
        page.get_by_label("Policy").select_option("none")
        page.wait_for_function("window.fleetgate.model.snap.policy === 'none'")
        if page.evaluate("window.fleetgate.status()") == "paused":
            page.get_by_role("button", name="Resume").click()
        finish_run(page)


def test_a_run_started_from_the_gui_gets_a_summary_line(page: Page,
                                                        demo: DemoProcess) -> None:
    before = sum("run complete" in line for line in demo.lines)
    fresh_run(page)
    finish_run(page)
    deadline = time.monotonic() + 10
    while sum("run complete" in line for line in demo.lines) == before:
        assert time.monotonic() < deadline, demo.lines[-5:]
        time.sleep(0.1)
    assert cells(page)  # the page is still live
