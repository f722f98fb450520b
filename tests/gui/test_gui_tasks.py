"""The GUI's task views on ``fleetgate demo --lifelong`` in headless Chromium: the queue, the
robots' tasks and errands, finished tasks, the throughput chart, and the operator's pause,
resume and cancel (checked against the task API itself)."""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any

import pytest
from playwright.sync_api import Browser, Page, expect

from tests.gui.conftest import ARTIFACTS
from tests.gui.demo_process import DemoProcess


@pytest.fixture(scope="module")
def shift() -> Iterator[DemoProcess]:
    """A lifelong demo: a generated warehouse, 6 robots, the task list streaming in."""
    with DemoProcess("--lifelong", "--robots", "6", "--speed", "5") as proc:
        yield proc


@pytest.fixture
def tasks_page(browser: Browser, shift: DemoProcess) -> Iterator[Page]:
    """The GUI on the shift; fails on any uncaught JavaScript error."""
    context = browser.new_context(viewport={"width": 1280, "height": 1000})
    pg = context.new_page()
    errors: list[str] = []
    pg.on("pageerror", lambda exc: errors.append(str(exc)))
    pg.goto(shift.url)
    expect(pg.locator("#tasks-card")).to_be_visible(timeout=20_000)
    yield pg
    ARTIFACTS.mkdir(parents=True, exist_ok=True)
    pg.screenshot(path=str(ARTIFACTS / "tasks.png"), full_page=True)
    context.close()
    assert not errors, f"JavaScript errors on the page: {errors}"


def api(page: Page, path: str) -> Any:
    """GET a task API path with the page's login (what the gateway says, not the page)."""
    return page.evaluate("async p => (await fetch(p, {credentials: 'same-origin'})).json()",
                         path)


def test_operator_pauses_resumes_and_cancels_tasks(tasks_page: Page) -> None:
    page = tasks_page
    queue = page.locator("#queue-rows tr")
    expect(queue.first).to_be_visible(timeout=20_000)
    first = int(queue.first.get_attribute("data-task") or -1)
    row = page.locator(f"#queue-rows tr[data-task='{first}']")  # rows are redrawn often
    row.get_by_role("button", name="Pause").click()
    expect(page.locator("#tasks-note")).to_have_text(f"task {first}: pause done")
    expect(row).to_have_attribute("data-state", "paused")
    assert api(page, f"/tasks/{first}")["state"] == "paused"
    # paused: it is not assigned, whatever the robots do meanwhile
    page.wait_for_timeout(1500)
    assert api(page, f"/tasks/{first}")["state"] == "paused"
    row.get_by_role("button", name="Resume").click()
    expect(page.locator("#tasks-note")).to_have_text(f"task {first}: resume done")
    assert api(page, f"/tasks/{first}")["state"] in ("queued", "assigned", "started",
                                                       "finished")
    target = page.locator("#queue-rows tr[data-state='queued'], #work-rows tr").filter(
        has=page.get_by_role("button", name="Cancel")).first
    victim = int(target.get_attribute("data-task") or -1)
    page.locator(f"button[data-act='cancel'][data-task='{victim}']").first.click()
    note = page.locator("#tasks-note")
    expect(note).not_to_have_text("")
    state = api(page, f"/tasks/{victim}")["state"]
    if note.text_content() == f"task {victim}: cancel done":
        assert state == "cancelled"
        expect(page.locator(f"#queue-rows tr[data-task='{victim}']")).to_have_count(0)
    else:  # its robot reached the first errand meanwhile: the gateway's precise refusal
        assert "is started" in (note.text_content() or "") and state != "cancelled"


def test_robots_tasks_finished_list_and_throughput(tasks_page: Page) -> None:
    page = tasks_page
    finished = page.locator("#finished-list li")
    expect(finished.first).to_be_visible(timeout=60_000)
    work = page.locator("#work-rows tr")
    expect(work.first).to_be_visible()
    # the robots' rows are what the gateway says (robots and tasks change while we look:
    # the two must agree at some moment)
    agreed = []
    for _ in range(40):
        shown_work = {(r, t) for r, t in page.evaluate(  # at once: rows are redrawn often
            "() => [...document.querySelectorAll('#work-rows tr')]"
            ".map(tr => [...tr.cells].slice(0, 2).map(td => Number(td.textContent)))")}
        busy = api(page, "/tasks?state=assigned,started")["tasks"]
        if shown_work and shown_work == {(t["robot"], t["id"]) for t in busy}:
            agreed.append(shown_work)
            break
        page.wait_for_timeout(150)
    assert agreed, "the page's robots and tasks never matched the gateway's"
    shown = [int(li.get_attribute("data-task") or -1) for li in finished.all()]
    for task in shown:
        assert api(page, f"/tasks/{task}")["state"] == "finished"
    bars = page.evaluate("window.fleetgate.tasks.bars")
    seen = page.evaluate("window.fleetgate.tasks.finishedAt.length")
    assert sum(bars) >= 1 and sum(bars) <= seen
    assert int(page.locator("#tasks-rate").text_content().split()[0]) <= seen
