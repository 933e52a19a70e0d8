"""Issue 17 in a real browser: Debian's Chromium driven by Playwright shows the dashboard's
camera view and belt view of a simulated cell (``Rig`` from test_ui_camera: run in virtual
time until parts are queued, then served as it stands), and takes the screenshots in
docs/operator-ui.md (docs/operator-camera.png, docs/operator-belt.png). A few seconds.
"""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest
from test_ui_browser import ARGS, CHROMIUM
from test_ui_camera import PASSWORD, Rig

pytestmark = pytest.mark.browser

ROOT = Path(__file__).resolve().parent.parent
SHOTS = {"camera": ROOT / "docs" / "operator-camera.png",
         "belt": ROOT / "docs" / "operator-belt.png"}

sync_api = pytest.importorskip("playwright.sync_api",
                               reason="Playwright for Python not installed (pip install -e "
                                      "'.[test]')")
expect = sync_api.expect


def shoot(locator, path: Path) -> None:
    tmp = path.with_suffix(".tmp.png")
    locator.screenshot(path=str(tmp))
    shutil.move(tmp, path)
    assert path.stat().st_size > 10_000


def test_camera_and_belt_views(tmp_path):
    rig = Rig(tmp_path)
    try:
        with sync_api.sync_playwright() as p:
            browser = p.chromium.launch(executable_path=CHROMIUM, args=ARGS)
            page = browser.new_page(viewport={"width": 1400, "height": 1000})
            page.goto(rig.url)
            page.fill("#login-user", "alice")
            page.fill("#login-password", PASSWORD)
            page.click("#login-submit")
            expect(page.locator("#dashboard")).to_be_visible()

            # the camera view: the current frame's picture and its parts, as located
            look = rig.ui.camera.slot.get()
            img = page.locator("#camera-img")
            expect(img).to_have_attribute("data-seq", str(look.seq), timeout=10_000)
            page.wait_for_function(
                "() => document.getElementById('camera-img').naturalWidth === 640")
            expect(page.locator("#camera-list .cam-part")).to_have_count(
                len(look.result.parts))
            expect(page.locator("#camera-list .cam-reject")).to_have_count(
                len(look.result.rejected))
            d = look.result.parts[0]
            expect(page.locator("#camera-list .cam-part").first).to_contain_text(
                f"{d.part}/{d.pose}")
            expect(page.locator("#camera-info")).to_contain_text(f"frame {look.frame.index}:")

            # the belt view: one shape per queued part (and the one being picked)
            queued = rig.cell.ctx.queue.peek_all()
            expect(page.locator("#belt-parts g.part:not(.picking)")).to_have_count(
                len(queued))
            first = page.locator(f'#belt-parts g[data-id="{queued[0].id}"]')
            expect(first).to_have_count(1)
            shown = rig.ui.belt.snapshot()      # what the status carries (the cell is still)
            x, y = shown["parts"][0]["x_mm"], shown["parts"][0]["y_mm"]
            assert first.get_attribute("transform") == f"translate({x:g} {y:g})"
            pick = shown["picking"]
            expect(page.locator("#belt-parts g.picking")).to_have_count(
                1 if pick and pick["phase"] == "pick" else 0)
            expect(page.locator("#belt-info")).to_contain_text(f"{len(queued)} part(s) queued")
            expect(page.locator("#belt .camera-window")).to_have_count(1)
            expect(page.locator("#belt .reach path")).to_have_count(1)

            shoot(page.locator("#camera-panel"), SHOTS["camera"])
            shoot(page.locator("#belt-panel"), SHOTS["belt"])
            browser.close()
    finally:
        rig.close()
