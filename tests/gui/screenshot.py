"""Write docs/gui.png: the GUI during the run ``fleetgate demo`` makes with its defaults.

Usage: ``.venv/bin/python -m tests.gui.screenshot [OUT.png]``. Runs the demo exactly as
``bash scripts/demo.sh`` does (lab map, 10 robots, the seed-0 intruder, slack policy,
threshold 2 s, speed 1; only the port is a free one) and takes the picture shortly after the
slack-triggered replan has been adopted and the robots are on their way again.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

from playwright.sync_api import sync_playwright

from tests.gui.demo_process import CHROMIUM, CHROMIUM_ARGS, DemoProcess

DOCS = Path(__file__).resolve().parents[2] / "docs"
AFTER_S = 1.2
"""How long after the new plan the picture is taken (seconds)."""


def main(out: Path) -> None:
    """Run the demo and save a 1440x900 screenshot of the GUI to ``out``."""
    with DemoProcess() as demo, sync_playwright() as pw:
        browser = pw.chromium.launch(executable_path=str(CHROMIUM), args=CHROMIUM_ARGS)
        page = browser.new_page(viewport={"width": 1440, "height": 900})
        page.goto(demo.url)
        page.wait_for_function("window.fleetgate && window.fleetgate.plan() >= 1",
                               timeout=60_000)
        time.sleep(AFTER_S)
        out.parent.mkdir(parents=True, exist_ok=True)
        page.screenshot(path=str(out))
        browser.close()
    print(out)


if __name__ == "__main__":
    main(Path(sys.argv[1]) if len(sys.argv) > 1 else DOCS / "gui.png")
