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


def intruder_target(page: Page, ahead: int = 3) -> Cell:
    """A cell the robot with the longest way to go will enter in ``ahead`` moves, on which no
    robot stands now."""
    rs = robots(page)
    occupied = {(r["cell"][0], r["cell"][1]) for r in rs}
    for r in sorted(rs, key=lambda r: -len(r["remaining"])):
        if len(r["remaining"]) > ahead + 1:
            cell = (r["remaining"][ahead][0], r["remaining"][ahead][1])
            if cell not in occupied:
                return cell
    raise AssertionError(f"no robot has {ahead + 1} moves ahead: {rs}")


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
