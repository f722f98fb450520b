"""The GUI's login (headless Chromium against a real ``fleetgate demo``): no page holds the
operator token, a wrong token is refused with the gateway's reason, the right one opens the GUI
with an HttpOnly session cookie, and a page from another origin cannot open the operator
websocket with that cookie."""

from __future__ import annotations

from urllib.parse import urlsplit

import pytest
from playwright.sync_api import Browser, expect

from tests.gui.demo_process import DemoProcess

pytestmark = pytest.mark.gui


def test_login_cookie_and_origin(browser: Browser, demo: DemoProcess) -> None:
    url = urlsplit(demo.url)
    token = url.fragment.removeprefix("token=")
    base = f"{url.scheme}://{url.netloc}"
    assert len(token) >= 24
    context = browser.new_context()
    page = context.new_page()
    page.goto(f"{base}/")  # not logged in: sent to the login page
    expect(page).to_have_url(f"{base}/login")
    assert token not in page.content()
    page.fill("#login-token", "wrong-token")
    page.click("#login-submit")
    expect(page.locator("#login-error")).to_contain_text("bad token")
    page.fill("#login-token", token)
    page.click("#login-submit")
    page.wait_for_function("window.fleetgate && window.fleetgate.model.snap !== null")
    cookie = next(c for c in context.cookies() if c["name"] == "fleetgate_session")
    assert cookie["httpOnly"] and cookie["sameSite"] == "Strict"
    assert page.evaluate("document.cookie") == ""  # scripts cannot read it
    # another origin (localhost is not 127.0.0.1) cannot use the login
    other = context.new_page()
    other.goto(f"{url.scheme}://localhost:{url.port}/login")
    code = other.evaluate(f"""() => new Promise((resolve) => {{
        const ws = new WebSocket("ws://127.0.0.1:{url.port}/ws");
        ws.onopen = () => resolve("open");
        ws.onclose = (ev) => resolve(ev.code);
    }})""")
    assert code == 1006  # refused at the handshake
    context.close()
