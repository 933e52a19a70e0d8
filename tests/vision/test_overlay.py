"""The annotated image (``feeder locate --annotate``, the dashboard's camera view): an
angle arrow only where the angle means something, as long as the part, and labels that
do not cover each other on a crowded belt."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from feeder_bt.config import load_scenario
from feeder_bt.core.geometry import place_outline, pose_outline
from feeder_bt.sim.render import Renderer
from feeder_bt.vision.locator import Locator
from feeder_bt.vision.overlay import _overlap, draw
from feeder_bt.vision.pixels import Calibration

ROOT = Path(__file__).resolve().parents[2]


def _drawn(name: str, part: str, pose: str, places: list[tuple[float, float, float]]):
    sc, cell = load_scenario(ROOT / "scenarios" / name)
    cal = Calibration(cell.camera.calibration)
    loc = Locator(sc.vision, sc.parts, cal)
    ren = Renderer(cell.camera)
    rng = np.random.default_rng(2)
    loc.set_golden(ren.golden(rng))
    out = pose_outline(sc.parts[part], pose)
    img = ren.render([place_outline(out, x, y, a) for x, y, a in places], rng)
    result = loc.locate(img)
    return img, result, cal


def _green_columns(img: np.ndarray, result, cal) -> np.ndarray:
    """The image columns holding pixels of the parts' colour (dot, arrow: green over a
    third of the pixel), the labels' boxes left out."""
    drawn, parts, _ = draw(img, result, cal)
    b, g, r = (drawn[..., k].astype(int) for k in range(3))
    green = (g - r > 60) & (g - b > 60)          # the parts' green, anti-aliased or not
    for d in parts:
        if d["label_px"] is not None:
            x, y, w, h = d["label_px"]
            green[y:y + h, x:x + w] = False
    return np.flatnonzero(green.any(axis=0))


def test_no_angle_arrow_on_a_washer_and_one_as_long_as_the_lever():
    """A washer (any angle is right) gets its dot, no arrow; a lever's arrow reaches
    just past its end (33 mm from its centre), not a fixed 25 mm."""
    img, res, cal = _drawn("washers.yaml", "washer", "flat", [(300.0, 300.0, 0.0)])
    assert len(res.parts) == 1 and ("washer", "flat") not in res.angled
    assert np.ptp(_green_columns(img, res, cal)) <= 8           # the dot alone
    # the lever along the image's rows (the camera's u runs along the belt's y)
    img, res, cal = _drawn("levers.yaml", "lever", "face_up", [(300.0, 300.0, 90.0)])
    (d,) = res.parts
    cols = _green_columns(img, res, cal)
    assert 34.0 < (cols.max() - d.u_px) * cal.mm_per_px < 42.0


def test_labels_on_a_crowded_belt_cover_no_other_label():
    """Twelve washers in touching distance of each other: every label's box is clear of
    every other's (a label with no free place keeps its first line only)."""
    places = [(150.0 + 30 * (k % 4), 150.0 + 30 * (k // 4), 0.0) for k in range(12)]
    img, res, cal = _drawn("washers.yaml", "washer", "flat", places)
    _, parts, rejected = draw(img, res, cal)
    boxes = [d["label_px"] for d in parts + rejected if d["label_px"] is not None]
    assert len(parts) >= 10 and len(boxes) >= 10
    assert all(_overlap(a, b) == 0 for i, a in enumerate(boxes) for b in boxes[i + 1:])
