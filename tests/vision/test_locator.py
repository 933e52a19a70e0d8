"""The renderer and the OpenCV locator on rendered frames of the simulated cell.

Recipes and parts come from the shipped scenario YAMLs, so these tests also check that
the recipes in ``scenarios/`` work on rendered images.
"""

from __future__ import annotations

import copy
import dataclasses
import math
from pathlib import Path

import cv2
import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from feeder_bt.config import load_cell, load_scenario
from feeder_bt.core.geometry import circumradius, place_outline, pose_outline, wrap_deg
from feeder_bt.core.model import (
    CameraCalibration,
    CameraSpec,
    PartSpec,
    Threshold,
    VisionRecipe,
)
from feeder_bt.sim.render import Renderer
from feeder_bt.vision.features import FEATURES
from feeder_bt.vision.locator import LocateResult, Locator
from feeder_bt.vision.pixels import Calibration

ROOT = Path(__file__).resolve().parents[2]
POS_TOL_MM = 1.0
ANGLE_TOL_DEG = 2.0


# ------------------------------------------------------------------ loading


def build_camera(calibration: CameraCalibration | None = None, **render) -> CameraSpec:
    """The simulated cell's camera, optionally with another calibration or render settings."""
    cam = copy.deepcopy(load_cell(ROOT / "cells" / "sim.yaml").camera)
    if calibration is not None:
        cam.calibration = calibration
    cam.render = dataclasses.replace(cam.render, **render)
    return cam


def load(scenario: str) -> tuple[dict[str, PartSpec], VisionRecipe]:
    sc, _ = load_scenario(ROOT / "scenarios" / f"{scenario}.yaml")
    return sc.parts, sc.vision


# ------------------------------------------------------------------ scene helpers


class Scene:
    """One camera, its renderer (truth == calibration) and a locator with a golden image."""

    def __init__(self, scenario: str, seed: int, camera: CameraSpec | None = None,
                 recipe: VisionRecipe | None = None) -> None:
        self.parts, rec = load(scenario)
        self.recipe = recipe or rec
        self.camera = camera or build_camera()
        self.cal = Calibration(self.camera.calibration)
        self.renderer = Renderer(self.camera)
        self.locator = Locator(self.recipe, self.parts, self.cal)
        self.rng = np.random.default_rng(seed)
        self.locator.set_golden(self.renderer.golden(self.rng))

    def random_layout(self, n: int, margin_px: float = 3.0, gap_mm: float = 8.0,
                      pose: str | None = None) -> list[dict]:
        """Up to ``n`` parts wholly inside the image, no two closer than ``gap_mm``."""
        w, h = self.camera.width_px, self.camera.height_px
        placed: list[dict] = []
        for _ in range(n * 50):
            if len(placed) == n:
                break
            name = str(self.rng.choice(sorted(self.parts)))
            part = self.parts[name]
            names = sorted(part.poses)
            probs = np.array([part.poses[p].probability for p in names])
            pn = pose or str(self.rng.choice(names, p=probs / probs.sum()))
            u, v = self.rng.uniform(0, w), self.rng.uniform(0, h)
            x, y = self.cal.px_to_mm([[u, v]])[0]
            outline = pose_outline(part, pn)
            r = circumradius(outline)
            if any(math.hypot(x - q["x"], y - q["y"]) < r + q["r"] + gap_mm for q in placed):
                continue
            angle = float(self.rng.uniform(-180.0, 180.0))
            placed_outline = place_outline(outline, x, y, angle)
            px = self.cal.mm_to_px(placed_outline)
            if px.min() < margin_px or px[:, 0].max() > w - 1 - margin_px \
                    or px[:, 1].max() > h - 1 - margin_px:
                continue
            placed.append({"part": name, "pose": pn, "x": x, "y": y, "angle": angle, "r": r,
                           "pickable": part.poses[pn].pickable,
                           "outline": placed_outline})
        return placed

    def shoot(self, layout: list[dict]) -> LocateResult:
        return self.locator.locate(self.renderer.render([p["outline"] for p in layout], self.rng))


def _match(result: LocateResult, truth: dict):
    near = [d for d in result.parts
            if math.hypot(d.x_mm - truth["x"], d.y_mm - truth["y"]) < 10.0]
    return near[0] if len(near) == 1 else None


def _check_singulated(scene: Scene, frames: int, per_frame: int, oriented: set[str]) -> list:
    errors = []
    for _ in range(frames):
        layout = scene.random_layout(per_frame)
        result = scene.shoot(layout)
        assert len(result.parts) == len(layout), (layout, result)
        for t in layout:
            d = _match(result, t)
            assert d is not None, f"{t['part']}/{t['pose']} at {t['x']:.1f},{t['y']:.1f} not found"
            assert (d.part, d.pose, d.pickable) == (t["part"], t["pose"], t["pickable"])
            dist = math.hypot(d.x_mm - t["x"], d.y_mm - t["y"])
            assert dist <= POS_TOL_MM
            da = abs(wrap_deg(d.angle_deg - t["angle"])) if t["part"] in oriented else 0.0
            assert da <= ANGLE_TOL_DEG, (t, d)
            errors.append((dist, da))
    return errors


# ------------------------------------------------------------------ calibration


@pytest.mark.parametrize("rotation", [0.0, 30.0, -90.0, 137.5])
def test_calibration_round_trip(rotation):
    cal = Calibration(CameraCalibration(origin_mm=(80.0, -15.0), mm_per_px=0.8,
                                        rotation_deg=rotation))
    uv = np.random.default_rng(0).uniform(-50, 700, size=(200, 2))
    xy = cal.px_to_mm(uv)
    assert np.allclose(cal.mm_to_px(xy), uv, atol=1e-9)
    # distances scale by mm_per_px, and the mapping is a reflection (handedness flips)
    assert np.allclose(np.linalg.norm(xy[1:] - xy[:-1], axis=1),
                       0.8 * np.linalg.norm(uv[1:] - uv[:-1], axis=1))
    a, b = cal.px_to_mm([[1, 0]])[0] - cal.px_to_mm([[0, 0]])[0], \
        cal.px_to_mm([[0, 1]])[0] - cal.px_to_mm([[0, 0]])[0]
    assert a[0] * b[1] - a[1] * b[0] < 0
    assert cal.mm2_per_px2 == pytest.approx(0.64)


@given(ox=st.floats(-500, 500), oy=st.floats(-500, 500), s=st.floats(0.05, 5.0),
       rot=st.floats(-360, 360), u=st.floats(-1000, 1000), v=st.floats(-1000, 1000))
def test_calibration_round_trip_property(ox, oy, s, rot, u, v):
    cal = Calibration(CameraCalibration(origin_mm=(ox, oy), mm_per_px=s, rotation_deg=rot))
    xy = cal.px_to_mm([[u, v]])
    r = math.radians(rot)
    assert xy[0, 0] == pytest.approx(ox + s * (v * math.cos(r) - u * math.sin(r)), abs=1e-6)
    assert xy[0, 1] == pytest.approx(oy + s * (v * math.sin(r) + u * math.cos(r)), abs=1e-6)
    assert np.allclose(cal.mm_to_px(xy), [[u, v]], atol=1e-6)


def test_calibration_convention():
    cal = Calibration(CameraCalibration(origin_mm=(80.0, -15.0), mm_per_px=1.0))
    assert np.allclose(cal.px_to_mm([[0, 0]]), [[80.0, -15.0]])
    assert np.allclose(cal.px_to_mm([[0, 10]]), [[90.0, -15.0]])   # v runs along travel
    assert np.allclose(cal.px_to_mm([[10, 0]]), [[80.0, -5.0]])    # u runs across
    rot = Calibration(CameraCalibration(origin_mm=(0.0, 0.0), mm_per_px=2.0, rotation_deg=90.0))
    # x = -s u, y = s v at r = 90°
    assert np.allclose(rot.px_to_mm([[3, 4]]), [[-6.0, 8.0]])


# ------------------------------------------------------------------ renderer


def test_render_is_realistic():
    cam = build_camera()
    r = Renderer(cam)
    rng = np.random.default_rng(1)
    golden = r.golden(rng)
    assert golden.dtype == np.uint8 and golden.shape == (cam.height_px, cam.width_px)
    centre = golden[232:252, 310:330].astype(float).mean()
    corner = golden[:20, :20].astype(float).mean()
    assert centre == pytest.approx(cam.render.backlight, abs=3)
    assert corner < centre - 0.15 * cam.render.backlight        # vignetting
    other = r.golden(rng)
    noise = (golden.astype(float) - other)[200:280, 280:360].std() / math.sqrt(2)
    assert noise == pytest.approx(cam.render.noise_sigma, rel=0.25)
    disc = place_outline(pose_outline(load("lenses")[0]["lens"], "flat"), 322.0, 305.0, 0.0)
    img = r.render([disc], rng)
    u, v = r.calibration.mm_to_px([[322.0, 305.0]])[0]
    assert abs(img[int(v), int(u)] - cam.render.part_grey) < 15
    # the edge is graded (anti-aliasing and blur), not a hard step
    row = img[int(v), int(u) - 32:int(u) - 20].astype(int)
    assert any(cam.render.part_grey + 20 < g < golden[int(v), int(u) - 26] - 20 for g in row)
    far = place_outline(pose_outline(load("lenses")[0]["lens"], "flat"), 5000.0, 5000.0, 0.0)
    assert np.abs(r.render([far], np.random.default_rng(2)).astype(int)
                  - r.golden(np.random.default_rng(2))).max() == 0


# ------------------------------------------------------------------ locator: singulated


def test_lenses_singulated_found_within_tolerance():
    scene = Scene("lenses", seed=11)
    errors = _check_singulated(scene, frames=15, per_frame=6, oriented=set())
    assert len(errors) >= 60


def test_squares_singulated_found_with_face_and_angle():
    scene = Scene("squares", seed=12)
    errors = _check_singulated(scene, frames=20, per_frame=6, oriented={"square"})
    assert len(errors) >= 80
    assert max(a for _, a in errors) <= ANGLE_TOL_DEG


def test_mixed_lenses_and_squares():
    scene = Scene("lenses_and_squares", seed=13)
    errors = _check_singulated(scene, frames=15, per_frame=6, oriented={"square"})
    assert len(errors) >= 60


def test_both_square_faces_seen_and_told_apart():
    scene = Scene("squares", seed=14)
    for pose, pickable in (("face_up", True), ("face_down", False)):
        layout = scene.random_layout(5, pose=pose)
        result = scene.shoot(layout)
        assert len(result.parts) == len(layout) >= 3
        assert all(d.pose == pose and d.pickable == pickable for d in result.parts)
        assert all(d.features["mirrored"] == (pose == "face_down") for d in result.parts)


@pytest.mark.parametrize("rotation", [30.0, -75.0])
def test_rotated_camera(rotation):
    # pixel (320, 242) stays at the same belt point for every rotation
    r = math.radians(rotation)
    u, v = 320.0, 242.0
    ox = 80.0 + 242.0 - (v * math.cos(r) - u * math.sin(r))
    oy = -15.0 + 320.0 - (v * math.sin(r) + u * math.cos(r))
    cam = build_camera(CameraCalibration(origin_mm=(ox, oy), mm_per_px=1.0, rotation_deg=rotation))
    scene = Scene("lenses_and_squares", seed=15, camera=cam)
    errors = _check_singulated(scene, frames=8, per_frame=5, oriented={"square"})
    assert len(errors) >= 30


def test_finer_pixels():
    cam = build_camera(CameraCalibration(origin_mm=(150.0, 80.0), mm_per_px=0.5))
    scene = Scene("squares", seed=16, camera=cam)
    errors = _check_singulated(scene, frames=5, per_frame=2, oriented={"square"})
    assert len(errors) >= 8


def test_on_edge_lens_found_not_pickable():
    scene = Scene("lenses", seed=17)
    layout = scene.random_layout(4, pose="on_edge")
    result = scene.shoot(layout)
    assert len(result.parts) == len(layout) >= 3
    for t in layout:
        d = _match(result, t)
        assert d is not None and d.pose == "on_edge" and not d.pickable


# ------------------------------------------------------------------ locator: rejects


@pytest.mark.parametrize("scenario", ["lenses", "lenses_and_squares"])
def test_touching_lenses_rejected(scenario):
    scene = Scene(scenario, seed=18)
    lens = pose_outline(scene.parts["lens"], "flat")
    a = place_outline(lens, 250.0, 200.0, 0.0)
    b = place_outline(lens, 250.0 + 50.5 * math.cos(0.6), 200.0 + 50.5 * math.sin(0.6), 0.0)
    alone = place_outline(lens, 420.0, 480.0, 0.0)
    result = scene.locator.locate(scene.renderer.render([a, b, alone], scene.rng))
    assert [(round(d.x_mm), round(d.y_mm)) for d in result.parts] == [(420, 480)]
    assert len(result.rejected) == 1
    # the reason names the class nearest by area and the range the blob is outside
    reason = result.rejected[0].reason
    assert reason.startswith("no class; nearest ") and ": area_mm2 " in reason, reason
    assert float(reason.split("area_mm2 ")[1].split()[0]) > 3500
    assert result.rejected[0].features["area_mm2"] > 3500


def test_touching_squares_rejected():
    scene = Scene("squares", seed=19)
    sq = pose_outline(scene.parts["square"], "face_up")
    a = place_outline(sq, 250.0, 200.0, 10.0)
    b = place_outline(sq, 250.0, 250.0, 35.0)          # corners overlap the first square
    result = scene.locator.locate(scene.renderer.render([a, b], scene.rng))
    assert result.parts == []
    assert len(result.rejected) == 1
    assert result.rejected[0].reason.startswith("no class; nearest square/"), result.rejected


@pytest.mark.parametrize("scenario", ["lenses", "squares"])
def test_part_cut_by_border_rejected(scenario):
    scene = Scene(scenario, seed=20)
    name = next(iter(scene.parts))
    pose = next(iter(scene.parts[name].poses))
    outline = pose_outline(scene.parts[name], pose)
    x, y = scene.cal.px_to_mm([[12.0, 200.0]])[0]         # 12 px from the left edge
    x2, y2 = scene.cal.px_to_mm([[300.0, scene.camera.height_px - 8.0]])[0]
    img = scene.renderer.render([place_outline(outline, x, y, 20.0),
                                 place_outline(outline, x2, y2, 0.0)], scene.rng)
    result = scene.locator.locate(img)
    assert result.parts == []
    assert [d.reason for d in result.rejected] == ["touches border"] * 2


@pytest.mark.parametrize("scenario", ["lenses", "squares", "lenses_and_squares"])
@pytest.mark.parametrize("render", [{}, {"falloff": 0.35, "noise_sigma": 6.0}])
def test_empty_belt_gives_no_parts(scenario, render):
    scene = Scene(scenario, seed=21, camera=build_camera(**render))
    for _ in range(10):
        result = scene.locator.locate(scene.renderer.golden(scene.rng))
        assert result.parts == [] and result.rejected == []


def test_small_debris_rejected_as_too_small():
    scene = Scene("lenses", seed=22)
    speck = place_outline(np.array([[-5.0, -5.0], [5.0, -5.0], [5.0, 5.0], [-5.0, 5.0]]),
                          300.0, 300.0, 0.0)
    result = scene.locator.locate(scene.renderer.render([speck], scene.rng))
    assert result.parts == []
    assert [d.reason for d in result.rejected] == ["too small"]


# ------------------------------------------------------------------ recipe variants


@pytest.mark.parametrize("threshold,golden", [
    (Threshold("fixed", value=110), False),             # no golden image: invert and cut
    (Threshold("otsu", value=40), True),
    (Threshold("adaptive", block_px=151, c=-20), False),
])
def test_threshold_methods_find_lenses(threshold, golden):
    _, recipe = load("lenses")
    recipe.threshold, recipe.golden_image = threshold, golden
    scene = Scene("lenses", seed=23, recipe=recipe)
    errors = _check_singulated(scene, frames=4, per_frame=5, oriented=set())
    assert len(errors) >= 16


def test_principal_axis_orientation_of_on_edge_lens():
    _, recipe = load("lenses")
    recipe.orientation = "principal_axis"
    scene = Scene("lenses", seed=24, recipe=recipe)
    for angle in (-60.0, 0.0, 35.0, 89.0):
        o = place_outline(pose_outline(scene.parts["lens"], "on_edge"), 300.0, 300.0, angle)
        (d,) = scene.locator.locate(scene.renderer.render([o], scene.rng)).parts
        assert abs(wrap_deg(d.angle_deg - angle, 180.0)) < ANGLE_TOL_DEG


def test_locator_trusts_its_calibration_not_the_truth():
    # A camera whose real origin is 5 mm off the calibrated one: the locator, seeing only
    # pixels, reports positions off by the same 5 mm (it cannot know better).
    cam = build_camera()
    truth = CameraCalibration(origin_mm=(85.0, -15.0), mm_per_px=1.0, rotation_deg=0.0)
    parts, recipe = load("lenses")
    loc = Locator(recipe, parts, Calibration(cam.calibration))
    ren = Renderer(cam, truth=truth)
    rng = np.random.default_rng(25)
    loc.set_golden(ren.golden(rng))
    o = place_outline(pose_outline(parts["lens"], "flat"), 300.0, 300.0, 0.0)
    (d,) = loc.locate(ren.render([o], rng)).parts
    assert d.x_mm == pytest.approx(295.0, abs=POS_TOL_MM) and d.y_mm == pytest.approx(300.0, abs=1)


def test_annotate_draws_parts_and_rejects():
    scene = Scene("lenses", seed=26)
    layout = scene.random_layout(3)
    cut = place_outline(pose_outline(scene.parts["lens"], "flat"),
                        *scene.cal.px_to_mm([[5.0, 200.0]])[0], 0.0)
    img = scene.renderer.render([p["outline"] for p in layout] + [cut], scene.rng)
    result = scene.locator.locate(img)
    assert len(result.parts) == 3 and len(result.rejected) == 1
    out = scene.locator.annotate(img, result)
    assert out.shape == img.shape + (3,) and out.dtype == np.uint8
    colour = (out[..., 0] != out[..., 1]) | (out[..., 1] != out[..., 2])
    assert colour.sum() > 200


def test_locate_rejects_non_uint8():
    scene = Scene("lenses", seed=27)
    with pytest.raises(TypeError):
        scene.locator.locate(np.zeros((484, 640), dtype=np.float32))


def test_without_backlight_nothing_is_found():
    """A frame grabbed with the backlight off (a set-up mistake) finds nothing."""
    sc, cell = load_scenario(ROOT / "scenarios" / "lenses.yaml")
    renderer = Renderer(cell.camera)
    locator = Locator(sc.vision, sc.parts, Calibration(cell.camera.calibration))
    rng = np.random.default_rng(3)
    locator.set_golden(renderer.golden(rng))
    flat = pose_outline(sc.parts["lens"], "flat")
    outlines = [place_outline(flat, 200.0 + 90 * i, 300.0, 0.0) for i in range(3)]
    assert len(locator.locate(renderer.render(outlines, rng)).parts) == 3
    dark = (renderer.render(outlines, rng) * 0.08).astype(np.uint8)
    assert locator.locate(dark).parts == []


# ------------------------------------------------------------------ locator internals


def _random_mask(rng: np.random.Generator, h: int = 120, w: int = 160) -> np.ndarray:
    """Discs, bars and specks, some cut by the image's edges and corners, with noise."""
    mask = np.zeros((h, w), np.uint8)
    for _ in range(int(rng.integers(1, 7))):
        centre = (int(rng.integers(-5, w + 5)), int(rng.integers(-5, h + 5)))
        if rng.random() < 0.5:
            cv2.circle(mask, centre, int(rng.integers(1, 18)), 255, -1)
        else:
            size = (int(rng.integers(1, 30)), int(rng.integers(1, 12)))
            box = cv2.boxPoints((centre, size, float(rng.uniform(0, 180))))
            cv2.fillPoly(mask, [box.astype(np.int32)], 255)
    noise = rng.random((h, w))
    mask[noise < 0.01] = 255
    mask[noise > 0.995] = 0
    return mask


@pytest.mark.parametrize("open_px,close_px", [(3, 3), (0, 0), (5, 3), (4, 0), (0, 7), (9, 0)])
def test_contours_on_bands_equal_the_whole_frame(open_px, close_px):
    """The packed bands (with mirrors at the image's edges) give exactly the contours, in
    the same order, as morphology and findContours on the whole frame."""
    parts, recipe = load("lenses")
    recipe = dataclasses.replace(recipe, morphology=dataclasses.replace(
        recipe.morphology, open_px=open_px, close_px=close_px))
    loc = Locator(recipe, parts, Calibration(build_camera().calibration))
    rng = np.random.default_rng(open_px * 10 + close_px)
    for _ in range(150):
        mask = _random_mask(rng)
        whole = loc._morph(mask.copy())
        for full, chain in ((True, cv2.CHAIN_APPROX_NONE), (False, cv2.CHAIN_APPROX_SIMPLE)):
            want, _ = cv2.findContours(whole, cv2.RETR_EXTERNAL, chain)
            got = loc._contours(mask, full)
            assert len(got) == len(want)
            for g, w in zip(got, want, strict=True):
                assert np.array_equal(g, w)


def test_chain_corners_give_the_full_chain():
    from feeder_bt.vision.chains import _chain_steps, _full_chain
    rng = np.random.default_rng(5)
    for _ in range(100):
        mask = _random_mask(rng)
        full, _ = cv2.findContours(mask, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
        corners, _ = cv2.findContours(mask, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
        assert _chain_steps(list(corners)) == [len(c) for c in full]
        for f, c in zip(full, corners, strict=True):
            assert np.array_equal(_full_chain(c), f)
            mf, mc = cv2.moments(f), cv2.moments(c)
            assert all(mf[k] == pytest.approx(mc[k], rel=1e-12, abs=1e-9)
                       for k in ("m00", "m10", "m01"))


def test_smoothed_length_is_the_moving_average_length():
    from feeder_bt.vision.chains import WINDOW as _WINDOW
    from feeder_bt.vision.chains import _smooth_length
    rng = np.random.default_rng(6)
    for n in list(range(3, 40)) + [100, 101, 250, 255]:
        pts = rng.integers(0, 200, size=(n, 2)).astype(np.int32)
        if n < 2 * _WINDOW:
            want = cv2.arcLength(pts.astype(np.float32), True)
        else:
            means = np.array([pts[np.arange(i - 2, i + 3) % n].mean(axis=0) for i in range(n)])
            want = np.hypot(*(np.roll(means, -1, axis=0) - means).T).sum()
        assert _smooth_length(pts.reshape(-1, 1, 2)) == pytest.approx(want, rel=1e-6)


def test_cut_corner_signatures_at_once_equal_one_by_one():
    from feeder_bt.vision.corners import _corner_signature, _corner_signatures
    parts, _ = load("squares")
    outline = pose_outline(parts["square"], "face_up")
    rng = np.random.default_rng(7)
    outlines = []
    for _ in range(12):
        o = place_outline(outline if rng.random() < 0.5 else outline * [1.0, -1.0],
                          *rng.uniform(-100, 100, 2), float(rng.uniform(-180, 180)))
        outlines.append((o + rng.normal(0, 0.1, o.shape)).astype(np.float32))
    together = _corner_signatures(outlines)
    assert together == [_corner_signature(o) for o in outlines]
    assert all(s is not None for s in together)


def test_features_are_measured_only_as_far_as_the_classes_need():
    scene = Scene("lenses", seed=28)
    layout = scene.random_layout(4)
    img = scene.renderer.render([p["outline"] for p in layout], scene.rng)
    lean = scene.locator.locate(img)
    every = scene.locator.locate(img, all_features=True)
    assert [(d.part, d.pose, d.x_mm, d.y_mm) for d in lean.parts] == \
        [(d.part, d.pose, d.x_mm, d.y_mm) for d in every.parts]
    for d, e in zip(lean.parts + lean.rejected, every.parts + every.rejected, strict=True):
        assert "area_mm2" in d.features
        assert set(e.features) >= set(FEATURES)
        assert all(e.features[k] == pytest.approx(v, rel=1e-12) for k, v in d.features.items())
    flat = [d for d in lean.parts if d.pose == "flat"]
    assert flat and all(set(d.features) == {"area_mm2", "perimeter_mm", "circularity"}
                        for d in flat)
    measured = scene.locator.measure_blobs(img)
    assert all(set(m.features) == set(FEATURES) for m in measured)


def test_one_locator_serves_several_threads():
    from concurrent.futures import ThreadPoolExecutor
    scene = Scene("squares", seed=29)
    frames = [scene.renderer.render([p["outline"] for p in scene.random_layout(5)], scene.rng)
              for _ in range(8)]

    def answers(img: np.ndarray) -> list:
        return [(d.part, d.pose, d.x_mm, d.y_mm, d.angle_deg)
                for d in scene.locator.locate(img).parts]

    alone = [answers(f) for f in frames]
    with ThreadPoolExecutor(4) as pool:
        for _ in range(3):
            assert list(pool.map(answers, frames)) == alone
