"""The dashboard in a real browser: Debian's Chromium driven by Playwright against a real
`feeder run scenarios/lenses.yaml --ui` on loopback (the simulated cell in real time).

What must be shown: (1) alice takes control and starts the cell and sees the total fed
rise; bob, in a second browser context, sees the same live and is told that someone else
has control, and his start/stop/speed requests are refused and change nothing; (3) a
horizontal speed set in the page reaches the simulated conveyor, the status and the
report; (4) the dashboard's screenshot (docs/operator-ui.png with --update-shots) is
taken here while the cell feeds. (2), wrong passwords, is shown here once and in full in
test_http.py.

The tests share one run and one browser, in file order (about 40 s, most of it waiting
for the first lenses to travel up the incline and reach the robot).
"""

from __future__ import annotations

import re

import pytest

from tests.support.browser_helpers import login, new_page, require_browser
from tests.support.uiutil import FeederUi, make_users

pytestmark = pytest.mark.browser

PASSWORDS = {"alice": "alice-secret-1", "bob": "bob-secret-22"}
FEED_WAIT_MS = 60_000        # the first part needs ~20 s from start at the lenses' speeds
SPEED = 173                  # not a value the water-marks adjuster (5 mm/s steps) would pick

sync_api = require_browser()
expect = sync_api.expect


@pytest.fixture(scope="module")
def server(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("ui_browser")
    ui = FeederUi(tmp, make_users(tmp / "users.json", PASSWORDS))
    yield ui
    ui.kill()


@pytest.fixture(scope="module")
def alice(browser, server):
    page = new_page(browser)
    login(page, server.url, "alice", PASSWORDS["alice"])
    expect(page.locator("#dashboard")).to_be_visible()
    yield page
    page.context.close()


@pytest.fixture(scope="module")
def bob(browser, server):
    """bob's page, not logged in yet (he logs in while the cell warms up)."""
    page = new_page(browser)
    yield page
    page.context.close()


def bob_logs_in(bob, server) -> None:
    if bob.locator("#dashboard").is_visible():
        return
    login(bob, server.url, "bob", "not-bobs-password")
    expect(bob.locator("#login-error")).to_have_text("wrong user name or password")
    expect(bob.locator("#dashboard")).to_be_hidden()
    login(bob, server.url, "bob", PASSWORDS["bob"])
    expect(bob.locator("#dashboard")).to_be_visible()


def total(page) -> int:
    return int(page.inner_text("#st-total"))


def feeding(alice) -> None:
    """alice holds control and the cell is feeding (whatever ran before)."""
    state = alice.locator("#control-state")
    if state.get_attribute("data-state") != "you":
        alice.click("#take")
        expect(state).to_have_text("Control: you have control")
    if alice.inner_text("#st-state") == "STOPPED":
        alice.click("#start")
    expect(alice.locator("#st-state")).to_have_text("RUNNING", timeout=15_000)
    expect(alice.locator("#st-total")).not_to_have_text("0", timeout=FEED_WAIT_MS)


def test_alice_controls_bob_watches(alice, bob, server):
    expect(alice.locator("#control-state")).to_have_text("Control: available")
    expect(alice.locator("#st-state")).to_have_text("STOPPED")     # --ui waits for an operator
    alice.click("#take")
    expect(alice.locator("#control-state")).to_have_text("Control: you have control")
    alice.click("#start")
    expect(alice.locator("#notice")).to_have_text(re.compile("start: the cell is STARTING"))

    # bob logs in (a wrong password first) and sees the same, live, and that someone
    # else has control
    bob_logs_in(bob, server)
    expect(bob.locator("#control-state")).to_have_text(
        "Control: someone else has control (alice)")
    expect(bob.locator("#st-state")).to_have_text("RUNNING", timeout=15_000)
    expect(bob.locator("#st-users")).to_have_text("alice, bob")

    # bob's requests are refused with the reason
    for button in ("#stop", "#start", "#pause"):
        bob.click(button)
        expect(bob.locator("#notice")).to_have_text("refused: alice has control")
    bob.fill("#horizontal", "250")
    bob.click("#set-horizontal")
    expect(bob.locator("#notice")).to_have_text("refused: alice has control")
    bob.click("#adjust-off")
    expect(bob.locator("#notice")).to_have_text("refused: alice has control")
    bob.click("#take")
    expect(bob.locator("#notice")).to_have_text(re.compile("refused: alice has control"))

    # ... and changed nothing: still feeding, alice still in control, no 250 mm/s anywhere
    expect(alice.locator("#st-state")).to_have_text("RUNNING")
    expect(alice.locator("#control-state")).to_have_text("Control: you have control")
    expect(alice.locator("#adjust-state")).to_have_text("water_marks, engaged")
    assert "250" not in alice.inner_text("#st-speeds")
    assert "250" not in alice.inner_text("#st-hal-horizontal")
    assert "bob: " not in alice.inner_text("#messages").replace("bob: logged in", "")

    # the total fed rises, on alice's page and on bob's
    expect(alice.locator("#st-total")).not_to_have_text("0", timeout=FEED_WAIT_MS)
    first = total(alice)
    expect(alice.locator("#st-total")).not_to_have_text(str(first), timeout=FEED_WAIT_MS)
    assert total(alice) > first
    expect(bob.locator("#st-total")).not_to_have_text(re.compile(rf"^(0|{first})$"),
                                                      timeout=10_000)
    assert total(bob) > first and bob.inner_text("#st-last").startswith("lens #")
    assert bob.inner_text("#st-state") == "RUNNING"


def test_dashboard_screenshot(alice, bob, server, shots):
    feeding(alice)
    bob_logs_in(bob, server)                        # two users in the status
    expect(alice.locator("#chart-ppm polyline")).to_have_count(1)
    expect(alice.locator("#tree")).to_contain_text("retrieve")
    shots.take(alice, "operator-ui.png", 20_000, full_page=True)


def test_a_closed_page_shows_the_others_when_control_will_be_free(alice, bob, server):
    """Alice's page goes away while she holds control, and bob is shown the
    count-down to control being free; her page back within that time, she keeps it."""
    feeding(alice)
    bob_logs_in(bob, server)
    alice.goto("about:blank")                       # her tab closed (the websocket with it)
    expect(bob.locator("#control-state")).to_have_text(re.compile(
        r"^Control: someone else has control \(alice\) \u2014 control free in [1-6]?\d s$"),
        timeout=5_000)
    alice.goto(server.url)                          # back: a reload does not lose control
    expect(alice.locator("#control-state")).to_have_text("Control: you have control")
    expect(bob.locator("#control-state")).to_have_text(
        "Control: someone else has control (alice)")


def test_speed_set_in_the_page_reaches_the_cell_and_the_report(alice, bob, server):
    feeding(alice)
    bob_logs_in(bob, server)
    alice.click("#adjust-off")                      # hold the adjuster, or it would move it
    expect(alice.locator("#adjust-state")).to_have_text("water_marks, disengaged")
    alice.fill("#horizontal", str(SPEED))
    alice.click("#set-horizontal")
    expect(alice.locator("#notice")).to_have_text(f"speeds set: horizontal_mm_s {SPEED}")
    # what the conveyor's controller reports, on both pages
    expect(alice.locator("#st-hal-horizontal")).to_have_text(f"{SPEED} mm/s", timeout=5_000)
    expect(bob.locator("#st-hal-horizontal")).to_have_text(f"{SPEED} mm/s", timeout=5_000)
    expect(alice.locator("#st-speeds")).to_contain_text(f"horizontal {SPEED} mm/s")
    expect(alice.locator("#messages")).to_contain_text(
        f"alice: set horizontal speed (mm/s) {SPEED}")
    alice.wait_for_timeout(1500)                    # three adjust periods: still held
    expect(alice.locator("#st-hal-horizontal")).to_have_text(f"{SPEED} mm/s")

    report = server.stop()                          # Ctrl-C: stop in order, write the report
    assert report["state"] == "STOPPED" and report["fault"] is None
    assert 20 < report["feed_seconds"] < 300 and report["parts_per_minute"] > 0
    assert report["speeds"]["horizontal_mm_s"] == SPEED
    assert sum(report["parts"]["retrieved"].values()) > 0 and report["parts"]["lost"] == 0
    commands = report["operator"]["commands"]
    assert {"user": "alice", "action": "speeds", "horizontal_mm_s": SPEED} in [
        {k: v for k, v in c.items() if k != "t"} for c in commands]
    assert {c["action"] for c in commands if c["user"] == "bob"} == {"logged in"}
