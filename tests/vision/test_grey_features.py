"""Brightness features in class ranges: ``grey_mean`` and ``grey_std`` (the frame's grey
inside the blob). Brass and steel washers of one outline under a front light differ only
in them; each drawn washer is named by the metal it was drawn in."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np

from feeder_bt.config import check_files, load_scenario
from feeder_bt.core.geometry import place_outline, pose_outline
from feeder_bt.sim.render import Renderer
from feeder_bt.vision.locator import Locator
from feeder_bt.vision.pixels import Calibration

ROOT = Path(__file__).resolve().parents[2]
GREY = {"brass": 185, "steel": 110}        # each metal's lit top surface, grey levels


def _washers(tmp_path: Path) -> Path:
    parts = "".join(f"  {n}:\n    shape: {{disc: {{diameter_mm: 24}}}}\n"
                    f"    poses: {{flat: {{probability: 1.0, pickable: true}}}}\n"
                    f"    symmetry: 360\n    place: {{x: {1330 - 60 * k}, y: -120, z: 0}}\n"
                    for k, n in enumerate(GREY))
    p = tmp_path / "metals.yaml"
    p.write_text(f"name: metals\ncell: {ROOT / 'cells' / 'sim_frontlit.yaml'}\nparts:\n{parts}"
                 "hopper:\n  parts: {brass: 100, steel: 100}\n"
                 "vision:\n  backlight: false\n  foreground: light\n"
                 "  threshold: {method: fixed, value: 50}\n  min_area_mm2: 100\n  classes:\n"
                 "    - {part: brass, pose: flat, pickable: true, area_mm2: [360, 520], "
                 "grey_mean: [155, 235]}\n"
                 "    - {part: steel, pose: flat, pickable: true, area_mm2: [360, 520], "
                 "grey_mean: [90, 150], grey_std: [5, 40]}\n"
                 "  orientation: none\n")
    return p


def test_brass_and_steel_of_one_outline_are_told_apart_by_their_grey(tmp_path):
    p = _washers(tmp_path)
    assert check_files([str(p)]) == []          # no grey range checked against a drawing
    sc, cell = load_scenario(p)
    cam = cell.camera
    ren = {n: Renderer(dataclasses.replace(cam, render=dataclasses.replace(cam.render,
                                                                           part_grey=g)))
           for n, g in GREY.items()}
    loc = Locator(sc.vision, sc.parts, Calibration(cam.calibration))
    rng = np.random.default_rng(4)
    loc.set_golden(np.maximum(ren["brass"].golden(rng), ren["steel"].golden(rng)))
    outline = pose_outline(sc.parts["brass"], "flat")
    named = 0
    for _ in range(4):
        truth = [(str(rng.choice(list(GREY))), 130.0 + 90 * (k % 5), 120.0 + 130 * (k // 5))
                 for k in range(15)]
        frame = np.maximum(*(ren[n].render([place_outline(outline, x, y, 0.0)
                                            for m, x, y in truth if m == n], rng)
                             for n in GREY))
        res = loc.locate(frame)
        assert not res.rejected
        for d in res.parts:
            m, _, _ = min(truth, key=lambda t: math.hypot(t[1] - d.x_mm, t[2] - d.y_mm))
            assert d.part == m and "grey_mean" in d.features
            named += 1
    assert named == 60
