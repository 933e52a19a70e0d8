"""The reported point is the part's area centroid with its holes taken out (the part
frame's origin, docs/scenarios.md), not the filled outline's: on a lever with two bores of
10 and 5 mm the filled outline's centroid lies about a millimetre and a half off."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from feeder_bt.config import load_scenario
from feeder_bt.core.geometry import circumradius, place_outline, pose_outline
from feeder_bt.sim.render import Renderer
from feeder_bt.vision.locator import Locator
from feeder_bt.vision.pixels import Calibration

ROOT = Path(__file__).resolve().parents[2]


def _bore(cx: float, d: float, n: int = 32) -> list[list[float]]:
    return [[round(cx + d / 2 * math.cos(2 * math.pi * k / n), 4),
             round(d / 2 * math.sin(2 * math.pi * k / n), 4)] for k in range(n)]


def lever_scenario(tmp_path: Path) -> Path:
    """A 90 x 20 mm lever, a 10 mm bore 10 mm from one end and a 5 mm bore beside it, as a
    scenario of its own (the washers' recipe, a class for the lever)."""
    text = (ROOT / "scenarios" / "washers.yaml").read_text()
    text = text.replace("cell: ../cells/", f"cell: {ROOT / 'cells'}/")
    holes = [_bore(-35.0, 10.0), _bore(-20.0, 5.0)]
    shape = ("shape: {polygon: {points_mm: [[-45, -10], [45, -10], [45, 10], [-45, 10]], "
             f"holes_mm: {holes}}}}}")
    text = text.replace("shape: {disc: {diameter_mm: 24, hole_mm: 10}}", shape)
    grips = text[text.index("    pick:\n"):text.index("  slug:\n")]
    text = text.replace(grips, "    pick: {grips: [{offset_mm: [20, 0]}], cup_radius_mm: 3}\n")
    text = text.replace("area_mm2: [420, 490], holes: [1, 1], hole_area_mm2: [60, 100]",
                        "area_mm2: [1650, 1950], holes: [2, 2]")
    p = tmp_path / "levers.yaml"
    p.write_text(text)
    return p


def centroid_errors(path: Path, frames: int = 12, seed: int = 5) -> list[float]:
    """Distances (mm) from each located lever's point to the true part-frame origin."""
    sc, cell = load_scenario(path)
    cam = cell.camera
    renderer = Renderer(cam, truth=cam.calibration)          # the truth is the calibration
    cal = Calibration(cam.calibration)
    locator = Locator(sc.vision, sc.parts, cal)
    rng = np.random.default_rng(seed)
    locator.set_golden(renderer.golden(rng))
    outline = pose_outline(sc.parts["washer"], "flat")
    r = circumradius(outline)
    errors: list[float] = []
    for _ in range(frames):
        truth = []
        for u in (110.0, 320.0, 530.0):
            for v in (90.0, 240.0, 390.0):
                x, y = cal.px_to_mm([[u + rng.uniform(-20, 20), v + rng.uniform(-20, 20)]])[0]
                truth.append((x, y, float(rng.uniform(-180, 180))))
        img = renderer.render([place_outline(outline, x, y, a) for x, y, a in truth], rng)
        found = [d for d in locator.locate(img).parts if d.part == "washer"]
        assert len(found) == len(truth)
        for x, y, _ in truth:
            errors.append(min(math.hypot(d.x_mm - x, d.y_mm - y) for d in found
                              if math.hypot(d.x_mm - x, d.y_mm - y) < r))
    return errors


def test_a_lever_with_two_bores_is_reported_at_its_area_centroid(tmp_path):
    errors = centroid_errors(lever_scenario(tmp_path))
    assert len(errors) == 108
    # the filled outline's centroid: 1.83 mm off on average, 2.23 at most; the area
    # centroid: 0.21 and 0.63 (the same lever without bores: 0.15 and 0.54)
    assert float(np.mean(errors)) < 0.3 and max(errors) < 0.8, (np.mean(errors), max(errors))
