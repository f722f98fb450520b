"""Fixtures: a real ``fleetgate demo`` subprocess and headless Chromium pages on its GUI."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest
from playwright.sync_api import Browser, Page, sync_playwright

from tests.gui.demo_process import CHROMIUM, CHROMIUM_ARGS, DemoProcess

ARTIFACTS = Path(__file__).resolve().parents[2] / "test-artifacts" / "gui"
SPEED = 3.0
"""World speed of the tests: an action lasts 333 ms of wall time, long enough to see a robot
between its two cells, short enough that a run of the lab instance (makespan 16) takes ~6 s."""


@pytest.fixture(scope="module")
def demo() -> Iterator[DemoProcess]:
    """``fleetgate demo`` on the lab map (10 robots), no automatic intruder, policy none; its
    first run starts at once (not at the first login: the tests take turns on it)."""
    with DemoProcess("--speed", str(SPEED), "--no-intruder", "--policy", "none", "--start",
                     "now") as proc:
        yield proc


@pytest.fixture(scope="module")
def browser() -> Iterator[Browser]:
    """Headless Chromium (the system one: never ``playwright install``)."""
    if not CHROMIUM.exists():
        pytest.skip(f"{CHROMIUM} is missing (scripts/test.sh installs it)")
    with sync_playwright() as pw:
        b = pw.chromium.launch(executable_path=str(CHROMIUM), args=CHROMIUM_ARGS, headless=True)
        yield b
        b.close()


@pytest.fixture
def page(browser: Browser, demo: DemoProcess, request: pytest.FixtureRequest) -> Iterator[Page]:
    """The GUI open in a fresh page; screenshot to test-artifacts/gui/ afterwards; fails the
    test on any uncaught JavaScript error."""
    context = browser.new_context(viewport={"width": 1280, "height": 800})
    pg = context.new_page()
    errors: list[str] = []
    pg.on("pageerror", lambda exc: errors.append(str(exc)))
    pg.goto(demo.url)
    pg.wait_for_function("window.fleetgate && window.fleetgate.model.snap !== null")
    yield pg
    ARTIFACTS.mkdir(parents=True, exist_ok=True)
    pg.screenshot(path=str(ARTIFACTS / f"{request.node.name}.png"))
    context.close()
    assert not errors, f"JavaScript errors on the page: {errors}"
