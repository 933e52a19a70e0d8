"""The dashboard's layout in a real browser (Debian's Chromium under Playwright) against a
real `feeder run scenarios/lenses.yaml --ui` on loopback, the cell running and the page's
user holding control.

What must be shown: at 1366x768 the page does not scroll, and the control panel, the
state, the tree and the camera each lie inside the viewport; at 1920x1080 too, and at
1366x657 (what a browser's tabs and address bar leave of a 1366x768 screen). And the
buttons say what applies: while the cell runs and you hold control, Start, Resume and
Take control are disabled (someone without control keeps them, to be told why not).

The measure is the browser's own: ``document.scrollingElement.scrollHeight`` against the
window's height, and each element's ``getBoundingClientRect()``.
"""

from __future__ import annotations

import pytest

from tests.support.browser_helpers import login, require_browser
from tests.support.uiutil import FeederUi, make_users

pytestmark = pytest.mark.browser

PASSWORDS = {"alice": "alice-secret-1", "bob": "bob-secret-22"}
SIZES = [(1366, 768), (1920, 1080), (1366, 657)]   # the last: 1366x768 less a browser's bars
#: what an operator must see without scrolling: control, state, the tree, the camera
MUST_SEE = {"control": "#control-panel", "state": "#state-badge",
            "tree": "#tv-scroll", "camera": "#camera-img"}

sync_api = require_browser()
expect = sync_api.expect

MEASURE = """sel => {
  const se = document.scrollingElement;
  const boxes = {};
  for (const [name, s] of Object.entries(sel)) {
    const el = document.querySelector(s);
    const r = el ? el.getBoundingClientRect() : null;
    boxes[name] = r && {top: r.top, left: r.left, bottom: r.bottom, right: r.right,
                        width: r.width, height: r.height};
  }
  return {scrollHeight: se.scrollHeight, scrollWidth: se.scrollWidth,
          innerHeight: window.innerHeight, innerWidth: window.innerWidth, boxes};
}"""


@pytest.fixture(scope="module")
def server(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("ui_layout")
    ui = FeederUi(tmp, make_users(tmp / "users.json", PASSWORDS))
    yield ui
    ui.kill()


@pytest.fixture(scope="module")
def alice(browser, server):
    """alice's page: logged in, holding control, the cell started and a frame shown."""
    page = browser.new_context(viewport={"width": 1366, "height": 768}).new_page()
    login(page, server.url, "alice", PASSWORDS["alice"])
    expect(page.locator("#dashboard")).to_be_visible()
    page.click("#take")
    expect(page.locator("#control-state")).to_have_text("Control: you have control")
    page.click("#start")
    expect(page.locator("#st-state")).to_have_text("RUNNING", timeout=15_000)
    page.wait_for_function("() => document.querySelector('#camera-img').naturalWidth > 0",
                           timeout=15_000)
    expect(page.locator("#tv-graph g.tv-node").first).to_be_visible()
    yield page
    page.context.close()


def measure(page, width: int, height: int) -> dict:
    page.set_viewport_size({"width": width, "height": height})
    page.wait_for_timeout(300)                      # a frame or two to lay out again
    return page.evaluate(MEASURE, MUST_SEE)


@pytest.mark.parametrize("width,height", SIZES)
def test_the_dashboard_fits_the_screen_without_scrolling(alice, width, height):
    m = measure(alice, width, height)
    print(f"{width}x{height}: page {m['scrollWidth']}x{m['scrollHeight']} px")
    assert m["scrollHeight"] <= m["innerHeight"], (
        f"the page scrolls at {width}x{height}: {m['scrollHeight']} px tall")
    assert m["scrollWidth"] <= m["innerWidth"], (
        f"the page scrolls sideways at {width}x{height}: {m['scrollWidth']} px wide")
    for name, box in m["boxes"].items():
        assert box is not None and box["width"] > 0 and box["height"] > 0, f"{name}: {box}"
        assert (box["top"] >= 0 and box["left"] >= 0 and box["bottom"] <= height
                and box["right"] <= width), f"{name} outside {width}x{height}: {box}"


def test_the_buttons_that_do_not_apply_are_disabled(alice, browser, server):
    alice.set_viewport_size({"width": 1366, "height": 768})
    expect(alice.locator("#st-state")).to_have_text("RUNNING")
    for button in ("#start", "#resume", "#take"):
        expect(alice.locator(button)).to_be_disabled()
    for button in ("#pause", "#stop", "#release"):
        expect(alice.locator(button)).to_be_enabled()
    alice.click("#pause")
    expect(alice.locator("#st-state")).to_have_text("PAUSED", timeout=15_000)
    expect(alice.locator("#resume")).to_be_enabled()
    expect(alice.locator("#pause")).to_be_disabled()
    alice.click("#resume")
    expect(alice.locator("#st-state")).to_have_text("RUNNING", timeout=15_000)

    # bob, without control, keeps his buttons: a click tells him who has control
    bob = browser.new_context(viewport={"width": 1366, "height": 768}).new_page()
    try:
        login(bob, server.url, "bob", PASSWORDS["bob"])
        expect(bob.locator("#control-state")).to_have_text(
            "Control: someone else has control (alice)")
        for button in ("#start", "#take"):
            expect(bob.locator(button)).to_be_enabled()
        bob.click("#start")
        expect(bob.locator("#notice")).to_have_text("refused: alice has control")
    finally:
        bob.context.close()


def test_no_empty_notice_band(alice):
    """An empty notice takes no room (it was a 30 px band above the panels)."""
    alice.set_viewport_size({"width": 1366, "height": 768})
    alice.evaluate("() => { document.querySelector('#notice').textContent = ''; }")
    box = alice.locator("#notice").bounding_box()
    assert box is None or box["height"] == 0, box


@pytest.mark.parametrize("width,height", [(1366, 768)])
def test_blackboard_values_wrap_as_words_not_a_letter_a_line(alice, width, height):
    """The blackboard beside the tree is narrow; a long value (the located frame's
    summary) must get the side's width, not the sliver its key leaves."""
    measure(alice, width, height)
    alice.wait_for_function(
        "() => [...document.querySelectorAll('#tv-board td')].some(td => "
        "td.textContent.length > 30)", timeout=15_000)
    widths = alice.evaluate("""() => {
      const side = document.querySelector('#tv-board').getBoundingClientRect().width;
      const tds = [...document.querySelectorAll('#tv-board td')]
        .filter(td => td.textContent.length > 30);
      return {side, tds: tds.map(td => td.getBoundingClientRect().width)};
    }""")
    assert widths["tds"] and min(widths["tds"]) >= 0.8 * widths["side"], widths
