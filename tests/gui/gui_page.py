"""Reading and driving the operator GUI in a Playwright page (shared by tests and screenshot).

Everything read here is what the page itself holds (``window.fleetgate``, filled only from the
gateway's websocket messages) or shows in its DOM.
"""

from __future__ import annotations

import json
from typing import Any

from playwright.sync_api import Page, expect

Cell = tuple[int, int]


def robots(page: Page) -> list[dict[str, Any]]:
    """The robots as the page draws them: id, cell, pos (fractional while moving), activity,
    remaining (cells ahead, the current one first)."""
    result: list[dict[str, Any]] = page.evaluate("window.fleetgate.robots()")
    return result


def cells(page: Page) -> list[Cell]:
    """Each robot's cell, from the page."""
    return [(r["cell"][0], r["cell"][1]) for r in robots(page)]


def wait_moved(page: Page, before: list[Cell], timeout_ms: float = 5_000) -> None:
    """Until some robot's cell differs from ``before``."""
    page.wait_for_function(
        "prev => JSON.stringify(window.fleetgate.robots().map(r => r.cell)) !== prev",
        arg=json.dumps([list(c) for c in before], separators=(",", ":")), timeout=timeout_ms)


def set_speed(page: Page, speed: float) -> None:
    """Move the speed slider (its change event sends set_speed) and wait for the gateway."""
    slider = page.get_by_label("Speed")
    slider.fill(str(speed))
    slider.dispatch_event("change")
    page.wait_for_function(f"window.fleetgate.model.snap.speed === {speed}")


def intruder_target(page: Page, seconds: float) -> Cell:
    """Where an intruder placed now for ``seconds`` of plan time surely delays the fleet: a
    cell robot r enters at step k in 4-9 that no robot is on or enters before step 4 (so the
    intruder takes it at once, even if placing it takes a while).

    r then waits about ``seconds - k`` steps there, and every robot that enters a cell r
    leaves afterwards waits too (the ADG's Type 2 edges): ``i + 1 + seconds - k - m`` steps
    if r leaves the cell at step i + 1 and the other robot enters it at step m (steps counted
    from now, 1 s of plan time each). Among the cells where that makes another robot wait at
    least 2 s (so that the fleet slack clearly rises), the one r reaches last is chosen.
    """
    paths = [[(c[0], c[1]) for c in r["remaining"]] for r in robots(page)]
    near = {c for p in paths for c in p[:4]}
    best: tuple[int, float, Cell] | None = None
    for r, p in enumerate(paths):
        for k in range(4, min(10, len(p))):
            if p[k] in near or p[k] == p[k - 1]:
                continue
            wait = max((i + 1 + seconds - k - m
                        for i in range(k, len(p) - 1) if p[i] != p[i + 1]
                        for o, q in enumerate(paths) if o != r
                        for m in range(i + 1, len(q)) if q[m] == p[i] != q[m - 1]),
                       default=0.0)
            if wait >= 2 and (best is None or (k, wait, p[k]) > best):
                best = (k, wait, p[k])
    assert best is not None, f"no intruder cell delays another robot by 2 s: {paths}"
    return best[2]


def place_intruder(page: Page, cell: Cell, seconds: float) -> None:
    """Arm "Place intruder", click ``cell`` on the map, wait until the page shows it there."""
    page.get_by_label("for (s)").fill(str(seconds))
    button = page.get_by_role("button", name="Place intruder")
    button.click()
    expect(button).to_have_attribute("aria-pressed", "true")
    xy = page.evaluate(f"window.fleetgate.cellCenter({cell[0]}, {cell[1]})")
    page.mouse.click(xy["x"], xy["y"])
    expect(button).to_have_attribute("aria-pressed", "false")
    page.wait_for_function(
        f"window.fleetgate.model.snap.intruders.some(c => c[0] === {cell[0]}"
        f" && c[1] === {cell[1]})", timeout=5_000)
