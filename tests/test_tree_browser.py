"""Issue 17 in a real browser (Playwright, Debian's Chromium): `feeder replay FILE.db --ui`
over a fast fault run; dragging the timeline back before the fault redraws the trees in
the colours they had then (the same statuses `feeder replay --at T --json` prints, which
test_tree_replay.py checks against the live trees), "End" resumes. The live dashboard's
tree view is checked over HTTP. Writes docs/tree-rewind.png."""

from __future__ import annotations

import json
import re
import shutil
import subprocess
import sys
import time
from pathlib import Path

import pytest
from test_ui_http import Client, FeederUi, make_users

from feeder_bt.run import RunOptions, run_job

pytestmark = pytest.mark.browser

CHROMIUM = "/usr/bin/chromium"
ARGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
        "--disable-background-networking", "--disable-component-update", "--disable-sync"]
ROOT = Path(__file__).resolve().parent.parent
SHOT = ROOT / "docs" / "tree-rewind.png"
FAULT_AT = 40.0
PLAN = f"seed: 0\nscripted:\n  - {{at_s: {FAULT_AT}, kind: estop, release_after_s: 5}}\n"
FILL = {"invalid": "rgb(238, 240, 242)", "running": "rgb(219, 234, 254)",
        "success": "rgb(209, 250, 229)", "failure": "rgb(254, 226, 226)"}

if not Path(CHROMIUM).exists():
    pytest.skip(f"{CHROMIUM} not found: install Debian's chromium package",
                allow_module_level=True)
sync_api = pytest.importorskip("playwright.sync_api", reason="Playwright not installed")
expect = sync_api.expect


def cli(*args: str) -> str:
    p = subprocess.run([sys.executable, "-m", "feeder_bt.cli", *args], capture_output=True,
                       text=True, timeout=60, cwd=ROOT)
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
    err = tmp / "stderr.txt"
    with err.open("w") as f:
        proc = subprocess.Popen([sys.executable, "-m", "feeder_bt.cli", "replay", str(db),
                                 "--ui", "127.0.0.1:0"], stderr=f, stdout=subprocess.DEVNULL,
                                cwd=ROOT)
    end, url = time.monotonic() + 30, ""
    while not url:
        m = re.search(r"replay UI: (http://127\.0\.0\.1:\d+/)", err.read_text())
        if m:
            url = m.group(1)
        elif proc.poll() is not None or time.monotonic() > end:
            proc.kill()
            raise AssertionError(err.read_text())
        else:
            time.sleep(0.05)
    yield db, url
    proc.terminate()
    proc.wait(10)


@pytest.fixture(scope="module")
def page():
    with sync_api.sync_playwright() as p:
        b = p.chromium.launch(executable_path=CHROMIUM, args=ARGS)
        pg = b.new_page(viewport={"width": 1400, "height": 1000})
        yield pg
        b.close()


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


def test_drag_the_timeline_back_before_the_fault_and_resume(replay, page):
    db, url = replay
    page.goto(url)
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
    SHOT.parent.mkdir(exist_ok=True)
    tmp = SHOT.with_suffix(".tmp.png")
    page.screenshot(path=str(tmp), full_page=True)
    shutil.move(tmp, SHOT)

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
