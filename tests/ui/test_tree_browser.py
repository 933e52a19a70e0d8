"""The trees' replay in a real browser (Playwright, Debian's Chromium): `feeder replay FILE.db --ui`
over a fast fault run; dragging the timeline back before the fault redraws the trees in
the colours they had then (the same statuses `feeder replay --at T --json` prints, which
test_tree_replay.py checks against the live trees), "End" resumes. The live dashboard's
tree view is checked over HTTP. Its screenshot is docs/tree-rewind.png (with
--update-shots)."""

from __future__ import annotations

import json
import re
import time

import pytest

from feeder_bt.app.run import RunOptions, run_job
from tests.support.browser_helpers import new_page, require_browser
from tests.support.uiutil import PASSWORD, ROOT, Client, FeederUi, ReplayUi, feeder_cli, make_users

pytestmark = pytest.mark.browser

FAULT_AT = 40.0
PLAN = f"seed: 0\nscripted:\n  - {{at_s: {FAULT_AT}, kind: estop, release_after_s: 5}}\n"
FILL = {"invalid": "rgb(238, 240, 242)", "running": "rgb(219, 234, 254)",
        "success": "rgb(209, 250, 229)", "failure": "rgb(254, 226, 226)"}

sync_api = require_browser()
expect = sync_api.expect


def cli(*args: str) -> str:
    p = feeder_cli(*args)
    assert p.returncode == 0, p.stderr
    return p.stdout


@pytest.fixture(scope="module")
def replay(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("tree_browser")
    (tmp / "plan.yaml").write_text(PLAN)
    db = tmp / "feeder.db"
    run_job(RunOptions(scenario=str(ROOT / "scenarios/lenses.yaml"), duration=70.0,
                       fast=True, seed=2, view="none", db=str(db),
                       faults=str(tmp / "plan.yaml")))
    ui = ReplayUi(tmp, db)
    yield db, ui.url
    ui.stop()


def _log_in(pg, url: str) -> None:
    pg.goto(url)                            # the replay asks for a login first
    pg.fill("#login-user", "alice")
    pg.fill("#login-password", PASSWORD)
    pg.click("#login-submit")
    expect(pg.locator("#tv-time")).to_be_visible()


@pytest.fixture(scope="module")
def page(browser, replay):
    pg = new_page(browser)
    _log_in(pg, replay[1])
    yield pg
    pg.context.close()


def node(page, name: str):
    return page.locator(f'#tv-graph g.tv-node[data-name="{name}"]').first


def fill(page, name: str) -> str:
    """The computed fill of a node's box (asked again if it was redrawn meanwhile)."""
    for _ in range(50):
        got = node(page, name).locator("rect").evaluate("r => getComputedStyle(r).fill")
        if got:
            return got
        page.wait_for_timeout(100)
    return ""


def drag_to(page, fraction: float) -> None:
    box = page.locator("#tv-slider").bounding_box()
    y = box["y"] + box["height"] / 2
    page.mouse.move(box["x"] + box["width"] - 4, y)       # the thumb sits at the end
    page.mouse.down()
    page.mouse.move(box["x"] + 8 + (box["width"] - 16) * fraction, y, steps=8)
    page.mouse.up()


def test_replay_opens_a_second_before_the_first_fault_unfolded(replay, page):
    db, url = replay
    page.goto(url)
    expect(page.locator("#tv-time")).to_contain_text("1 s before the first fault")
    want = json.loads(cli("replay", str(db), "--before-fault", "--json"))
    assert float(page.locator("#tv-time").get_attribute("data-t")) == round(want["t"], 3)
    # the slider stands where the time shown is, not at 0 until End is pressed
    slider = float(page.locator("#tv-slider").input_value())
    assert abs(slider - round(want["t"], 3)) < 0.01, (slider, want["t"])
    expect(node(page, "feeder")).to_have_attribute("data-status", "running")
    running = [n["id"] for n in want["nodes"] if n["status"] == "running"]
    assert len(running) > 3
    for i in running:                        # the running branch is unfolded, every node
        expect(page.locator(f'#tv-graph g.tv-node[data-id="{i}"]')).to_have_attribute(
            "data-status", "running")


@pytest.mark.parametrize("width", [1280, 1920])
def test_the_tree_fits_its_box_and_pans_at_1_to_1(replay, browser, width):
    db, url = replay
    pg = browser.new_context(viewport={"width": width, "height": 1000}).new_page()
    try:
        _log_in(pg, url)
        expect(pg.locator("#tv-time")).to_contain_text("before the first fault")
        expect(pg.locator("#tv-graph g.tv-node").first).to_be_visible()

        def sizes() -> tuple[float, float, float]:
            return pg.evaluate("() => { const s = document.getElementById('tv-scroll'); "
                               "return [s.clientWidth, s.scrollWidth, "
                               "document.getElementById('tv-graph').getBoundingClientRect()"
                               ".right - s.getBoundingClientRect().right]; }")
        box, inner, over = sizes()
        assert inner <= box + 1 and over <= 1, (box, inner, over)   # nothing clipped
        pg.click("#tv-zoom")                                        # 1:1: wider; drag pans
        expect(pg.locator("#tv-zoom")).to_have_text("Zoom to fit")
        box, inner, _ = sizes()
        assert inner > box + 1 or width > 1280        # at 1280 the trees are wider than that
        if inner > box + 1:
            r = pg.locator("#tv-scroll").bounding_box()
            x0, y = r["x"] + r["width"] - 8, r["y"] + 4             # the background, above row 1
            under = pg.evaluate("([x, y]) => { const e = document.elementFromPoint(x, y); "
                                "return e.closest('.tv-node') ? 'a node' : e.id || e.tagName; }",
                                [x0, y])
            assert under in ("tv-graph", "tv-scroll"), under
            pg.mouse.move(x0, y)
            pg.mouse.down()
            pg.mouse.move(r["x"] + 8, y, steps=5)
            pg.mouse.up()
            # a loaded machine may hand the page its mouse events late: wait for the pan
            pg.wait_for_function("document.getElementById('tv-scroll').scrollLeft > 0",
                                 timeout=10_000)
        pg.click("#tv-zoom")
        box, inner, _ = sizes()
        assert inner <= box + 1
    finally:
        pg.context.close()


def test_drag_the_timeline_back_before_the_fault_and_resume(replay, page, shots):
    db, url = replay
    page.goto(url)
    # the replay opens 1 s before the first fault once its events are in: a click before
    # that would be undone by the opening
    expect(page.locator("#tv-time")).to_contain_text("before the first fault")
    page.click("#tv-live")                                 # "End": the end of the run
    expect(page.locator("#tv-time")).to_contain_text("end of the run")
    expect(node(page, "feeder")).to_have_attribute("data-status", "invalid")
    assert fill(page, "feeder") == FILL["invalid"]
    span = json.loads(cli("replay", str(db), "--json"))["t"]

    drag_to(page, (FAULT_AT - 1.0) / span)                # about a second before the fault
    # the last of the drag's requests answered: a time under FAULT_AT (40) s
    expect(page.locator("#tv-time")).to_have_attribute("data-t", re.compile(r"^[1-3]?\d(\.\d+)?$"))
    expect(page.locator("#tv-time")).to_contain_text("before the end")
    expect(node(page, "feeder")).to_have_attribute("data-status", "running")
    t = float(page.locator("#tv-time").get_attribute("data-t"))
    assert FAULT_AT - 4 < t < FAULT_AT
    want = json.loads(cli("replay", str(db), "--at", str(t), "--json"))
    by_id = {n["id"]: n["status"] for n in want["nodes"]}
    drawn = page.locator("#tv-graph g.tv-node")
    shown = [(int(g.get_attribute("data-id")), g.get_attribute("data-status"))
             for g in drawn.all()]
    assert len(shown) > 20 and all(by_id[i] == s for i, s in shown)
    assert {"running", "success"} <= {s for _, s in shown}
    for name in ("feeder", "retrieve loop"):
        assert fill(page, name) == FILL["running"]
    done = next(n["name"] for n in want["nodes"] if n["status"] == "success")
    assert fill(page, done) == FILL["success"]
    assert page.locator("#tv-board").inner_text().count("/speeds/") == 3
    shots.take(page, "tree-rewind.png", 20_000, full_page=True)

    # a folded (idle) branch opens on a click, showing its nodes
    before = page.locator("#tv-graph g.tv-node").count()
    folded = page.locator("#tv-graph g.tv-node.folded").first
    hidden = int(re.search(r"\+(\d+)$", folded.locator("text").last.text_content()).group(1))
    folded.click()
    expect(page.locator("#tv-graph g.tv-node")).to_have_count(before + hidden)

    page.click("#tv-back")                                 # one second further back
    expect(page.locator("#tv-time")).to_have_attribute("data-t", str(round(t - 1, 3)))
    page.click("#tv-play")                                 # play on from there
    expect(page.locator("#tv-play")).to_contain_text("Pause")
    expect(page.locator("#tv-time")).not_to_have_attribute("data-t", str(round(t - 1, 3)))
    assert float(page.locator("#tv-time").get_attribute("data-t")) > t - 1
    page.click("#tv-live")                                 # resume: the end of the run
    expect(page.locator("#tv-time")).to_contain_text("end of the run")
    expect(node(page, "feeder")).to_have_attribute("data-status", "invalid")
    assert fill(page, "feeder") == FILL["invalid"]


def test_live_dashboard_serves_the_trees_to_logged_in_users(tmp_path):
    ui = FeederUi(tmp_path, make_users(tmp_path / "users.json", {"alice": "alice-secret-1"}),
                  "--start")
    try:
        c = Client(ui.url)
        assert c.call("api/tree/at")[0] == 401
        c.login("alice", "alice-secret-1")
        end = time.monotonic() + 30
        while True:
            code, body, _ = c.call("api/tree/at")
            if code == 200 and body["tree"] == "feeding" or time.monotonic() > end:
                break
            time.sleep(0.2)
        assert code == 200 and body["live"] and body["tree"] == "feeding"
        assert [m[1] for m in body["marks"][:2]] == ["STARTING", "RUNNING"]
        code, nodes, _ = c.call("api/tree/nodes")
        assert len(nodes["nodes"]) == body["nodes"] == len(body["statuses"])
        code, early, _ = c.call("api/tree/at?t=0.5")
        assert code == 200 and early["tree"] == "setup"
        assert c.call("api/tree/at?t=inf")[0] == 400
    finally:
        ui.kill()
