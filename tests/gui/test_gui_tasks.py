"""The GUI's task views on ``fleetgate demo --lifelong`` in headless Chromium: the queue, the
robots' tasks and errands, finished tasks, the throughput chart, and the operator's pause,
resume and cancel (checked against the task API itself)."""

from __future__ import annotations

import re
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
    # the answer to this click (the note still says the resume's when the victim is `first`)
    expect(note).to_have_text(re.compile(rf"task {victim}: cancel done|is started"))
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
        shown_work = {(r, t) for r, *ts in page.evaluate(  # at once: rows are redrawn often
            "() => [...document.querySelectorAll('#work-rows tr')].map(tr => [tr.cells[0], "
            "tr.cells[1], ...tr.cells[3].textContent.split(', ').filter(Boolean)]"
            ".map(td => Number(td.textContent ?? td)))") for t in ts}
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
    # the rate is the gateway's (tasks per minute of the shift so far, as the terminal's)
    expect(page.locator("#tasks-rate")).to_have_text(re.compile(r"^\d+\.\d / min$"))


# ---------------------------------------------------------------------------- the live map
def gateway_snapshot(page: Page) -> Any:
    """The gateway's own state now: a snapshot on a second operator websocket with the page's
    login (opened once, then ``get_snapshot``), not the page's model."""
    return page.evaluate("""() => new Promise((ok, fail) => {
      let ws = window.testGateway;
      const ask = () => ws.send(JSON.stringify({
        v: 2, type: "get_snapshot", msg_id: `t${Date.now()}`, seq: 0}));
      const take = (m) => {
        const msg = JSON.parse(m.data);
        if (msg.type === "snapshot") { ws.removeEventListener("message", take); ok(msg); }
      };
      if (!ws) {
        const scheme = location.protocol === "https:" ? "wss" : "ws";
        ws = window.testGateway = new WebSocket(`${scheme}://${location.host}/ws`);
        ws.onerror = () => fail(new Error("websocket error"));
        ws.addEventListener("message", take);  // the snapshot on connect
      } else {
        ws.addEventListener("message", take);
        ask();
      }
    })""")


def on_way(page_cell: list[int], before: dict[str, Any], after: dict[str, Any],
           robot: int) -> bool:
    """Whether the page's cell of ``robot`` is one the gateway had it on between two of its
    snapshots: on its committed path from where it stood in ``before`` up to where it stands
    in ``after``."""
    path = before["paths"][robot]
    end = after["robots"][robot]["cell"]
    return page_cell == end or (end in path and page_cell in path[:path.index(end) + 1])


def test_the_map_shows_the_shift_live(tasks_page: Page) -> None:
    """The warehouse, each robot where the gateway has it (moving on as the shift runs, its
    heading), each busy robot's task errands with the next one marked, and robots paused."""
    page = tasks_page
    page.wait_for_function("() => { const s = window.fleetgate.model.snap;"
                           " return s && s.lifelong && window.fleetgate.drawn().length === 6; }",
                           timeout=20_000)
    snap = gateway_snapshot(page)
    assert snap["lifelong"] and page.evaluate("window.fleetgate.model.snap.rows") == snap["rows"]
    assert "robots" in (page.get_by_role("img", name="Map").get_attribute("aria-label") or "")
    # the robots move on the map as the shift runs
    drawn = page.evaluate("window.fleetgate.drawn().map(d => [d.id, d.x, d.y])")
    page.wait_for_function(
        "prev => window.fleetgate.drawn().filter(d => { const p = prev[d.id];"
        " return Math.hypot(d.x - p[1], d.y - p[2]) > 1; }).length >= 3",
        arg=drawn, timeout=20_000)
    # where the page draws them is where the gateway has them (the two must agree at a
    # moment: robots move on while we look)
    agreed = False
    last: Any = None
    for _ in range(40):
        before = gateway_snapshot(page)
        page.wait_for_timeout(50)  # events reach the page a little after the gateway
        shown = page.evaluate("window.fleetgate.robots()")
        after = gateway_snapshot(page)
        if all(on_way(r["cell"], before, after, r["id"]) for r in shown):
            agreed = True
            break
        last = [(r["cell"], before["paths"][r["id"]], after["robots"][r["id"]]["cell"])
                for r in shown]
    assert agreed, f"the page's robots never stood where the gateway had them: {last}"
    clock = page.evaluate("window.fleetgate.clock()")  # the page runs the shift's clock
    assert abs(clock - gateway_snapshot(page)["t_ms"]) < 5000.0
    # each robot is drawn on the canvas where the page's model has it (read in the frame the
    # map was just drawn in: within a fifth of a cell)
    off = page.evaluate("""async () => {
      await new Promise((ok) => requestAnimationFrame(ok));  // right after the map's frame
      const box = document.getElementById("map").getBoundingClientRect();
      const robots = window.fleetgate.robots();
      const [a, b] = [window.fleetgate.cellCenter(0, 0), window.fleetgate.cellCenter(1, 0)];
      return window.fleetgate.drawn().map((d, i) => {
        const c = window.fleetgate.cellCenter(...robots[i].pos);
        return Math.hypot(box.left + d.x - c.x, box.top + d.y - c.y) / (b.x - a.x);
      });
    }""")
    assert len(off) == 6 and max(off) < 0.2, off
    # a busy robot's task: its errand cells still to reach, the next one marked
    seen = False
    for _ in range(40):
        busy = api(page, "/tasks?state=assigned,started")["tasks"]
        errands = page.evaluate("window.fleetgate.drawnErrands()")
        for task in busy:
            want = [list(c) for c in task["errands"][task["errands_done"]:]]
            got = [e for e in errands if e["robot"] == task["robot"]]
            if want and [e["cell"] for e in got] == want and got[0]["next"] \
                    and got[0]["task"] == task["id"] and not any(e["next"] for e in got[1:]):
                seen = True
        if seen:
            break
        page.wait_for_timeout(150)
    assert seen, "no robot's task errands were drawn as the task API has them"
    # paused: every robot that is not moving wears the pause badge; resumed: none does
    page.locator("#btn-pause").click()
    page.wait_for_function("() => window.fleetgate.status() === 'paused' && "
                           "window.fleetgate.drawn().some(d => d.paused)")
    page.locator("#btn-resume").click()
    page.wait_for_function("() => window.fleetgate.status() === 'running' && "
                           "!window.fleetgate.drawn().some(d => d.paused)")


# ---------------------------------------------------------------------------- a long shift
def api_change(page: Page, method: str, path: str, body: Any = None) -> tuple[int, Any]:
    """A change through the task API with the page's login (status, answer)."""
    return tuple(page.evaluate(  # type: ignore[return-value]
        """async ([m, p, b]) => {
          const r = await fetch(p, {method: m, credentials: 'same-origin',
            headers: {'Content-Type': 'application/json'},
            body: b === null ? undefined : JSON.stringify(b)});
          return [r.status, await r.json()];
        }""", [method, path, body]))


def test_a_reloaded_page_shows_every_open_task_and_the_recent_finishes(
        tasks_page: Page) -> None:
    """After more than a page of tasks (1000), a page opened anew lists every open one (here
    three paused at the head of the queue, beyond the first thousand ids), counts them as
    the gateway does, and charts the finishes it did not see happen. Runs last: it leaves
    a thousand tasks queued."""
    page = tasks_page
    expect(page.locator("#finished-list li").first).to_be_visible(timeout=60_000)
    errands = api(page, "/tasks?limit=1")["tasks"][0]["errands"]
    assert api_change(page, "POST", "/tasks",
                      {"tasks": [{"errands": errands}] * 1000})[0] == 201
    status, made = api_change(page, "POST", "/tasks",
                              {"tasks": [{"errands": errands, "priority": 7}] * 3})
    held = [t["id"] for t in made["tasks"]]
    assert status == 201 and min(held) > 1000
    for task in held:
        assert api_change(page, "POST", f"/tasks/{task}/pause")[0] == 200
    before = api(page, "/tasks?limit=1")["counts"]
    page.reload()
    expect(page.locator("#tasks-card")).to_be_visible(timeout=20_000)
    expect(page.locator("#queue-rows tr").first).to_have_attribute("data-task", str(held[0]),
                                                                  timeout=20_000)
    head = page.evaluate("() => [...document.querySelectorAll('#queue-rows tr')].slice(0, 3)"
                         ".map(tr => [Number(tr.dataset.task), tr.dataset.state])")
    assert head == [[task, "paused"] for task in held]
    page.wait_for_function("n => window.fleetgate.tasks.bars &&"
                           " window.fleetgate.tasks.bars.reduce((a, b) => a + b, 0) >= n",
                           arg=before["finished"], timeout=20_000)  # all within 20 minutes
    counts = page.locator("#tasks-counts").text_content() or ""
    queued, paused = (int(n) for n in re.findall(r"(\d+) (?:queued|paused)", counts))
    finished = int(re.findall(r"(\d+) finished", counts)[0])
    assert paused == before["paused"] == 3
    assert before["queued"] >= 900 and queued >= before["queued"] - 50  # robots take a few
    assert finished >= before["finished"]
    for task in held:
        assert api_change(page, "DELETE", f"/tasks/{task}")[0] == 200


def test_the_interactive_docs_work_without_internet(browser: Browser, shift: DemoProcess) -> None:
    # /docs renders the task API's operations from the gateway's own files: every request the
    # page makes goes to the gateway (anything else is aborted and recorded, as on a warehouse
    # network without internet access)
    origin = re.match(r"https?://[^/#]+", shift.url)
    assert origin is not None
    context = browser.new_context()
    outside: list[str] = []

    def only_the_gateway(route: Any) -> None:
        if route.request.url.startswith(origin[0]):
            route.continue_()
        else:
            outside.append(route.request.url)
            route.abort()

    context.route("**/*", only_the_gateway)
    pg = context.new_page()
    pg.goto(origin[0] + "/docs")
    expect(pg.locator(".opblock-summary-path", has_text="/tasks").first).to_be_visible(
        timeout=20_000)
    paths = {t.strip() for t in pg.locator(".opblock-summary-path").all_inner_texts()}
    context.close()
    assert outside == []
    assert {"/tasks", "/tasks/{id}", "/tasks/events"} <= {p.replace("\u200b", "") for p in paths}
