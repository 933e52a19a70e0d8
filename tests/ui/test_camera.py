"""The dashboard's camera view and belt view, over HTTP against a real operator UI
(``OperatorUi`` serving on loopback) around a simulated cell run in virtual time until
parts are queued. The cell is not ticked while the tests ask: what the server answers
must match what the cell's locator and queue hold at that moment.

The rig (``ServedRig``, also driven by test_camera_browser.py) is in uiutil.py.
"""

from __future__ import annotations

import json
import time
import urllib.error
import urllib.request

import cv2
import numpy as np
import pytest

from feeder_bt.control.access import parse_setting
from feeder_bt.control.users import UsersError
from feeder_bt.ui.camera import Pacer
from feeder_bt.vision.pixels import Calibration
from tests.support.uiutil import Client, FakeClock, ServedRig


@pytest.fixture(scope="module")
def rig(tmp_path_factory):
    r = ServedRig(tmp_path_factory.mktemp("ui_camera"))
    yield r
    r.close()


def get(client: Client, path: str) -> tuple[int, bytes, dict]:
    try:
        with client.opener.open(client.base + path, timeout=20) as resp:
            return resp.status, resp.read(), resp.headers
    except urllib.error.HTTPError as e:
        return e.code, e.read(), e.headers


def fresh_pacer(rig: ServedRig) -> None:
    rig.ui.web.camera.pacer = Pacer()


def test_camera_shows_the_located_parts_of_the_current_frame(rig):
    fresh_pacer(rig)
    c = rig.client()
    code, body, _ = c.call("api/camera")
    assert code == 200 and body["ok"] and body["fps"] == 2
    look = rig.ui.camera.slot.get()
    assert body["seq"] == look.seq and body["frame"] == look.frame.index
    # what is drawn is the locator's result for this frame, part for part ...
    want = [(d.part, d.pose, round(d.x_mm, 1), round(d.y_mm, 1), round(d.angle_deg, 1))
            for d in look.result.parts]
    got = [(p["part"], p["pose"], p["x_mm"], p["y_mm"], p["angle_deg"]) for p in body["parts"]]
    assert got == want and len(got) >= 1
    assert [r["reason"] for r in body["rejected"]] == [d.reason for d in look.result.rejected]
    # ... and the locator finds the same parts in that very image again
    again = rig.cell.ctx.vision.locator.locate(look.frame.image)
    assert [(d.part, round(d.x_mm, 1), round(d.y_mm, 1)) for d in again.parts] == \
        [(p, x, y) for p, _, x, y, _ in want]
    # the picture: the frame's size, a green dot on each part, a red cross on each reject
    code, jpeg, headers = get(c, body["image"].lstrip("/"))
    assert code == 200 and headers["content-type"] == "image/jpeg"
    img = cv2.imdecode(np.frombuffer(jpeg, np.uint8), cv2.IMREAD_COLOR)
    assert img.shape[:2] == look.frame.image.shape == (body["height"], body["width"])

    def colour(d: dict) -> np.ndarray:
        u, v = round(d["u_px"]), round(d["v_px"])
        return img[v - 1:v + 2, u - 1:u + 2].reshape(-1, 3).mean(axis=0)   # B, G, R

    for p in body["parts"]:
        b, g, r = colour(p)
        assert g > 120 and g > r + 60 and g > b + 60, (p, (b, g, r))
    for d in body["rejected"]:
        b, g, r = colour(d)
        assert r > 120 and r > g + 60, (d, (b, g, r))
    # the frame under it is the camera's (a lens is dark where the belt is bright)
    grey = cv2.cvtColor(img, cv2.COLOR_BGR2GRAY).astype(int)
    assert abs(grey[5:40, 300:340].mean() - look.frame.image[5:40, 300:340].mean()) < 25


def test_camera_is_for_signed_in_users_only(rig):
    fresh_pacer(rig)
    seq = rig.ui.camera.slot.get().seq
    nobody = Client(rig.url)
    for path in ("api/camera", f"api/camera/{seq}.jpg"):
        code, body, _ = get(nobody, path)
        assert code == 401 and json.loads(body)["error"] == "not logged in"
    c = rig.client()
    assert get(c, "api/camera")[0] == 200
    assert c.call("api/logout", {})[0] == 200
    code, body, _ = get(c, f"api/camera/{seq}.jpg")
    assert code == 401


def test_camera_is_rate_limited_and_encodes_at_most_fps(rig):
    clock = FakeClock(time.monotonic() + 10.0)     # after the pictures earlier tests made
    rig.ui.web.camera.pacer = Pacer(clock)
    rig.ui.camera.clock = clock
    c = rig.client()
    rig.run_until_parts(after_seq=rig.ui.camera.slot.get().seq)
    code, first, _ = c.call("api/camera")          # a new frame: a picture made now
    assert first["seq"] == rig.ui.camera.slot.get().seq
    encodes = rig.ui.camera.encodes
    codes = [c.call("api/camera")[0] for _ in range(2)]
    assert [code, *codes] == [200, 200, 429]        # 2 fps, a burst of two
    code, body, headers = c.call("api/camera")
    assert code == 429 and headers["retry-after"] == "1"
    assert "at most 2 camera frames a second" in body["error"]
    other = rig.client()                            # another session has its own allowance
    assert other.call("api/camera")[0] == 200
    # a newer frame sooner than 1/fps after the last picture is skipped, not encoded
    rig.run_until_parts(after_seq=first["seq"])
    assert rig.ui.camera.slot.get().seq > first["seq"]
    code, body, _ = other.call("api/camera")
    assert code == 200 and body["seq"] == first["seq"] and rig.ui.camera.encodes == encodes
    clock.t += 0.5
    code, body, _ = c.call("api/camera")
    assert code == 200 and body["seq"] == rig.ui.camera.slot.get().seq > first["seq"]
    assert rig.ui.camera.encodes == encodes + 1
    # an old picture is gone once a new one is made
    assert get(c, first["image"].lstrip("/"))[0] in (404, 429)


def test_camera_fps_is_a_setting():
    assert parse_setting("camera_fps", "5") == 5.0
    for bad in ("0", "11", "fast", True, "nan"):
        with pytest.raises(UsersError, match="camera_fps: frames a second between 0.2 and 10"):
            parse_setting("camera_fps", bad)


def test_belt_view_is_the_part_queue_moved_by_the_encoder(rig):
    c = rig.client()
    belt = c.status()["belt"]
    ctx = rig.cell.ctx
    count = ctx.hal.robot_position.belt_encoder()
    enc = rig.cell.cell.encoder
    queued = ctx.queue.peek_all()
    assert belt["encoder"] == count and len(queued) >= 3
    assert [p["id"] for p in belt["parts"]] == [p.id for p in queued]
    for shown, part in zip(belt["parts"], queued, strict=True):
        assert shown["x_mm"] == round(part.x_at(count, enc.robot_bits, enc.counts_per_mm), 1)
        assert (shown["y_mm"], shown["type"]) == (round(part.y_mm, 1), part.type)
        assert shown["x_mm"] > part.x_mm            # moved downstream since its latch
    # the windows come from the cell's description and the scenario
    spec = rig.cell.cell
    assert belt["robot"] == {"base_mm": list(spec.robot.base_mm),
                             "reach_mm": spec.robot.reach_mm,
                             "inner_reach_mm": spec.robot.inner_reach_mm}
    # the window's corners through the cell's calibration (a tilted camera with a lens:
    # not an axis-aligned rectangle)
    w, h = spec.camera.width_px, spec.camera.height_px
    corners = Calibration(spec.camera.calibration).px_to_mm(
        np.array([[-0.5, -0.5], [w - 0.5, -0.5], [w - 0.5, h - 0.5], [-0.5, h - 0.5]]))
    assert belt["camera"] == [[round(x, 1), round(y, 1)] for x, y in corners]
    xs = sorted(x for x, _ in belt["camera"])
    assert xs[0] == pytest.approx(spec.camera.calibration.origin_mm[0], abs=3.0)
    assert xs[-1] - xs[0] == pytest.approx(h * spec.camera.calibration.mm_per_px, rel=0.02)
    assert belt["too_far_mm"] == rig.scenario.retrieve.too_far_mm
    # the part being picked is not in the queue any more, and is shown as such
    if belt["picking"] is not None:
        assert belt["picking"]["id"] not in {p.id for p in queued}
        assert belt["picking"]["phase"] in ("pick", "held", "place")
