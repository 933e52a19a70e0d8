"""The camera and belt views in a real browser: Debian's Chromium driven by Playwright shows the dashboard's
camera view and belt view of a simulated cell (``ServedRig`` from uiutil: run in virtual
time until parts are queued, then served as it stands), and takes the screenshots in
docs/operator-ui.md (docs/operator-camera.png, docs/operator-belt.png, with
--update-shots). A few seconds.
"""

from __future__ import annotations

import pytest

from tests.support.browser_helpers import login, new_page, require_browser
from tests.support.uiutil import PASSWORD, ServedRig

pytestmark = pytest.mark.browser

sync_api = require_browser()
expect = sync_api.expect


def test_camera_and_belt_views(tmp_path, browser, shots):
    rig = ServedRig(tmp_path)
    try:
        page = new_page(browser)
        login(page, rig.url, "alice", PASSWORD)
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

        shots.take(page.locator("#camera-panel"), "operator-camera.png", 10_000)
        shots.take(page.locator("#belt-panel"), "operator-belt.png", 10_000)
        page.context.close()
    finally:
        rig.close()
