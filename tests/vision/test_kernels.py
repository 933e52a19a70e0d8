"""The locator's compiled kernels (feeder_bt/vision/kernels.py) against the OpenCV calls and
numpy rules they replaced, on random inputs; and numba's import and cache behaviour."""

from __future__ import annotations

import math
import os
import subprocess
import sys
import threading

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from feeder_bt.vision.chains import WINDOW, _chain_steps
from feeder_bt.vision.jit import kernels
from feeder_bt.vision.pixels import Calibration

K = kernels()
_SIM = (K.SIMILARITY, np.zeros((1, 4, 3)), np.array([1.0, 0.0, 0.0, 1.0, 0.0, 0.0, 1.0]))


def _mask(seed: int, h: int = 90, w: int = 130) -> np.ndarray:
    """Discs, bars and specks, some cut by the edges, with noise."""
    rng = np.random.default_rng(seed)
    mask = np.zeros((h, w), np.uint8)
    for _ in range(int(rng.integers(1, 7))):
        centre = (int(rng.integers(-5, w + 5)), int(rng.integers(-5, h + 5)))
        if rng.random() < 0.5:
            cv2.circle(mask, centre, int(rng.integers(1, 25)), 255, -1)
        else:
            size = (int(rng.integers(1, 40)), int(rng.integers(1, 20)))
            box = cv2.boxPoints((centre, size, float(rng.uniform(0, 180))))
            cv2.fillPoly(mask, [box.astype(np.int32)], 255)
    noise = rng.random((h, w))
    mask[noise < 0.005] = 255
    mask[noise > 0.997] = 0
    return mask


def _stats(contours, full=True, length=True, hulls=True, min_px=0.0, table=_SIM):
    pts = np.ascontiguousarray(np.concatenate(contours).reshape(-1, 2))
    lens = np.array([len(c) for c in contours], dtype=np.int64)
    return pts, K.blob_stats(pts, lens, min_px, full, length, hulls, WINDOW, *table)


@settings(max_examples=60, deadline=None)
@given(st.integers(0, 10**6))
def test_blob_stats_are_opencvs_box_moments_hull_and_rectangle(seed):
    mask = _mask(seed)
    contours, _ = cv2.findContours(mask, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    if not contours:
        return
    pts, (boxes, stats, hull, hull_ends) = _stats(contours)
    for i, c in enumerate(contours):
        assert tuple(boxes[i]) == cv2.boundingRect(c)
        m = cv2.moments(c)
        row = stats[i]
        assert row[K.M00] == pytest.approx(m["m00"], rel=1e-12, abs=1e-12)
        if m["m00"]:
            assert row[K.CU] == pytest.approx(m["m10"] / m["m00"], rel=1e-12)
            assert row[K.CV] == pytest.approx(m["m01"] / m["m00"], rel=1e-12)
        else:
            assert (row[K.CU], row[K.CV]) == pytest.approx(tuple(c.reshape(-1, 2).mean(0)))
        assert row[K.STEPS] == len(c)
        # the hull: OpenCV's vertices (no collinear points)
        mine = pts[hull[(hull_ends[i - 1] if i else 0):hull_ends[i]]]
        theirs = cv2.convexHull(c).reshape(-1, 2)
        assert sorted(map(tuple, mine.tolist())) == sorted(map(tuple, theirs.tolist()))
        assert row[K.HULL_AREA] == cv2.contourArea(theirs)
        assert row[K.HULL_LEN] == pytest.approx(cv2.arcLength(theirs, True), rel=1e-9)
        # the minimum-area rectangle: the same area (its sides as the features use them)
        (_, _), (w, h), _ = cv2.minAreaRect(theirs)
        assert (row[K.RECT_W] + 1) * (row[K.RECT_H] + 1) == pytest.approx((w + 1) * (h + 1),
                                                                          rel=1e-5)


@settings(max_examples=30, deadline=None)
@given(st.integers(0, 10**6))
def test_blob_stats_count_a_corner_chains_boundary_pixels(seed):
    corners, _ = cv2.findContours(_mask(seed), cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
    if not corners:
        return
    _, (_, stats, _, _) = _stats(corners, full=False, length=False, hulls=False)
    assert stats[:, K.STEPS].astype(int).tolist() == _chain_steps(list(corners))
    assert np.isnan(stats[:, K.LENGTH]).all() and np.isnan(stats[:, K.RECT_W]).all()


def test_blob_stats_leave_specks_unmeasured():
    contours = [np.array([[[5, 5]], [[6, 5]]], np.int32), np.array([[[0, 0]]], np.int32)]
    _, (boxes, stats, _, _) = _stats(contours, min_px=2.5)
    assert boxes[0, 2] == -1 and boxes[1, 2] == -1 and np.isnan(stats).all()


@given(st.lists(st.tuples(st.floats(-50, 700), st.floats(-50, 530)), min_size=1, max_size=40))
def test_points_to_mm_through_a_similarity_are_the_calibrations(uv):
    from feeder_bt.core.model import CameraCalibration
    cal = Calibration(CameraCalibration(origin_mm=(80.3, -14.6), mm_per_px=0.9994,
                                        rotation_deg=-2.5))
    uv = np.array(uv, dtype=float)
    got = K.map_points(uv, *cal._kernel_table())
    assert np.allclose(got[:, :2], cal.px_to_mm(uv), rtol=0, atol=1e-9)
    assert np.all(got[:, 2] == cal.mm_per_px)


def _rois_reference(mask: np.ndarray, margin: int) -> list[tuple[int, int, int, int]]:
    """``Segmenter._rois``' rule, in numpy: an XY-cut, rows then columns then rows..., runs
    parted by more than 2 margin empty lines, each piece trimmed to its foreground, until
    neither way cuts; first pieces first."""
    def runs(idx):
        cuts = np.flatnonzero(np.diff(idx) > 2 * margin)
        return list(zip(np.r_[idx[0], idx[cuts + 1]], np.r_[idx[cuts], idx[-1]], strict=True))
    h, w = mask.shape
    out = []

    def cut(v0, v1, u0, u1, axis, stuck):
        lit = np.flatnonzero(mask[v0:v1, u0:u1].any(axis=1 - axis))
        pieces = runs(lit) if len(lit) else []
        for a, b in pieces:
            box = (v0 + a, v0 + b + 1, u0, u1) if axis == 0 else (v0, v1, u0 + a, u0 + b + 1)
            if stuck and len(pieces) == 1:
                out.append((max(box[0] - margin, 0), min(box[1] + margin, h),
                            max(box[2] - margin, 0), min(box[3] + margin, w)))
            else:
                cut(*box, 1 - axis, len(pieces) == 1)
    cut(0, h, 0, w, 0, False)
    return out


def test_foreground_rectangles_are_cut_until_tight():
    # two discs side by side, one tall and one short: one band of rows, two column runs;
    # the short one's rectangle is its own height, not the band's
    mask = np.zeros((80, 100), np.uint8)
    mask[10:70, 10:30] = 255
    mask[20:30, 60:80] = 255
    from feeder_bt.core.model import VisionRecipe
    from feeder_bt.vision.segment import Segmenter
    seg = Segmenter(VisionRecipe())
    seg._margin = 3
    assert [tuple(r) for r in seg._rois(mask).tolist()] == [(7, 73, 7, 33), (17, 33, 57, 83)]
    assert seg._rois(np.zeros((80, 100), np.uint8)).shape == (0, 4)


@settings(max_examples=60, deadline=None)
@given(st.integers(0, 10**6), st.integers(1, 6), st.integers(60, 140))
def test_foreground_rectangles_follow_the_rule(seed, margin, width):
    from feeder_bt.core.model import VisionRecipe
    from feeder_bt.vision.segment import Segmenter
    mask = _mask(seed, w=width)
    seg = Segmenter(VisionRecipe())
    seg._margin = margin
    assert [tuple(r) for r in seg._rois(mask).tolist()] == _rois_reference(mask, margin)
    # the scratch mask (rows padded to whole words) gives the same as a copy
    own = seg._buffer("mask", mask.shape)
    own[:] = mask
    assert [tuple(r) for r in seg._rois(own).tolist()] == _rois_reference(mask, margin)


def _grey(rng: np.random.Generator, h: int, w: int) -> np.ndarray:
    """A belt and parts: one or two grey modes with noise, or uniform noise, or flat."""
    kind = int(rng.integers(0, 4))
    if kind == 0:
        return rng.integers(0, 256, (h, w), dtype=np.uint8)
    if kind == 1:
        return np.full((h, w), int(rng.integers(0, 256)), np.uint8)
    img = rng.normal(rng.uniform(0, 255), rng.uniform(1, 40), (h, w))
    if kind == 3:
        parts = rng.random((h, w)) < rng.uniform(0.02, 0.5)
        img[parts] = rng.normal(rng.uniform(0, 255), rng.uniform(1, 40), int(parts.sum()))
    return np.clip(img, 0, 255).astype(np.uint8)


@settings(max_examples=80, deadline=None)
@given(st.integers(0, 10**6), st.integers(1, 130), st.integers(1, 130))
def test_otsu_level_of_the_sampled_difference_is_opencvs(seed, h, w):
    from feeder_bt.vision.segment import otsu_level, subsample
    rng = np.random.default_rng(seed)
    img, golden = _grey(rng, h, w), _grey(rng, h, w)
    small = subsample(golden).copy()

    def cv_otsu(sample: np.ndarray) -> float:
        return float(cv2.threshold(sample, 0, 255, cv2.THRESH_BINARY | cv2.THRESH_OTSU)[0])

    assert otsu_level(img) == cv_otsu(subsample(img))
    assert otsu_level(img, small, "minus_golden") == cv_otsu(
        cv2.subtract(subsample(img), small))
    assert otsu_level(img, small, "golden_minus") == cv_otsu(
        cv2.subtract(small, subsample(img)))


@settings(max_examples=60, deadline=None)
@given(st.integers(0, 10**6), st.integers(1, 40), st.integers(1, 90))
def test_the_frame_against_the_golden_image_is_opencvs_mask(seed, h, w):
    """``golden_mask``: the frame below the golden image less t (dark parts), above it plus
    t (light), as ``cv2.compare`` against the golden image moved by ``cv2.subtract`` /
    ``cv2.add`` (saturated), for every t from 0 to 255; the padding past the last pixel
    untouched."""
    rng = np.random.default_rng(seed)
    img, golden = _grey(rng, h, w), _grey(rng, h, w)
    pad = -(-w // 8) * 8
    for t in sorted({0, 1, 127, 128, 254, 255, *rng.integers(0, 256, 4).tolist()}):
        for light in (False, True):
            level = np.full_like(golden, t)
            want = (cv2.compare(img, cv2.add(golden, level), cv2.CMP_GT) if light
                    else cv2.compare(img, cv2.subtract(golden, level), cv2.CMP_LT))
            got = np.zeros((h, pad), np.uint8)
            K.golden_mask(img, golden, t, light, got)
            assert np.array_equal(got[:, :w], want), (t, light)
            assert not got[:, w:].any()


@pytest.mark.parametrize("value", [20.0, 70.0])        # 70: above Otsu's level here
@pytest.mark.parametrize("method", ["fixed", "otsu"])
@pytest.mark.parametrize("foreground", ["dark", "light"])
def test_the_golden_frame_in_one_call_is_the_same_as_step_by_step(method, foreground, value):
    """``Segmenter._threshold``'s level and mask against the golden image are OpenCV's
    (Otsu on the sample, compare against the moved golden image), and ``_segment``'s one
    call (``golden_morph``: the level, the mask, the packed morphology) finds the contours,
    holes and level that ``_threshold`` then ``_contours_holes`` find."""
    import dataclasses

    from feeder_bt.core.model import VisionRecipe
    from feeder_bt.vision.segment import Segmenter, subsample
    rng = np.random.default_rng(11)
    recipe = VisionRecipe()
    recipe = dataclasses.replace(recipe, foreground=foreground, golden_image=True,
                                 threshold=dataclasses.replace(recipe.threshold,
                                                               method=method, value=value))
    seg = Segmenter(recipe)
    golden = np.clip(rng.normal(128, 6, (120, 150)), 0, 255).astype(np.uint8)
    seg.set_golden(golden)
    for i in range(8):
        img = golden.copy()
        blobs = _mask(i, 120, 150) > 0
        img[blobs] = np.clip(img[blobs].astype(int) + (100 if foreground == "light" else -100),
                             0, 255).astype(np.uint8)
        img = cv2.GaussianBlur(img, (5, 5), 1.5)      # edges graded: the level matters
        mask, _, level = seg._threshold(img)
        # the level and mask by OpenCV, as before the kernel: Otsu's level of the sampled
        # difference, never below the recipe's, the golden image moved by its whole part
        small = subsample(golden)
        want = value if method == "fixed" else max(value, cv2.threshold(
            cv2.subtract(subsample(img), small) if foreground == "light"
            else cv2.subtract(small, subsample(img)),
            0, 255, cv2.THRESH_BINARY | cv2.THRESH_OTSU)[0])
        moved = np.full_like(golden, math.floor(want))
        assert level == want
        assert np.array_equal(mask, cv2.compare(img, cv2.add(golden, moved), cv2.CMP_GT)
                              if foreground == "light"
                              else cv2.compare(img, cv2.subtract(golden, moved), cv2.CMP_LT))
        step = seg._contours_holes(mask.copy(), True, True)
        contours, holes, diff, got_level = seg._segment(img, True, True)
        assert got_level == level and diff is None
        assert len(contours) == len(step[0]) and len(contours) > 0
        assert all(np.array_equal(a, b) for a, b in zip(contours, step[0], strict=True))
        assert [len(h) for h in holes] == [len(h) for h in step[1]]


def _edge_reference(hulls, diff, cut):
    """``Segmenter._edge_points``' rule in numpy (as before the kernels)."""
    du, dv = np.array([1, -1, 0, 0]), np.array([0, 0, 1, -1])
    w = diff.shape[1]
    uv = np.concatenate(hulls).reshape(-1, 2)
    counts = [len(c) for c in hulls]
    at = (uv[:, 1] * w + uv[:, 0])[:, None] + np.array([0, 1, -1, w, -w])
    vals = diff.ravel()[at]
    inside, around = vals[:, 0], vals[:, 1:]
    i, k = ((around <= cut) & (inside > cut)[:, None]).nonzero()
    last = np.searchsorted(i, np.cumsum(counts))
    found = last.copy()
    found[1:] -= last[:-1]
    if found.min() < 3:
        return uv.astype(float), counts
    a = inside[i].astype(np.float64)
    t = (a - (cut + 0.5)) / (a - around[i, k])
    return np.column_stack([uv[i, 0] + t * du[k], uv[i, 1] + t * dv[k]]), found.tolist()


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 10**6), st.integers(40, 200))
def test_edge_points_follow_the_rule(seed, cut):
    rng = np.random.default_rng(seed)
    diff = cv2.GaussianBlur(_mask(seed), (7, 7), 1.5)
    diff = np.clip(diff.astype(int) + rng.integers(-8, 9, diff.shape), 0, 255).astype(np.uint8)
    inner = np.zeros_like(diff)
    inner[1:-1, 1:-1] = (diff[1:-1, 1:-1] > cut) * 255
    contours, _ = cv2.findContours(inner, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    contours = [c for c in contours if len(c) > 4]
    if not contours:
        return
    pts, (_, _, hull, hull_ends) = _stats(contours, length=False)
    sel = np.arange(len(contours), dtype=np.int64)
    got, ends = K.edge_points(pts, hull, hull_ends, sel, diff.reshape(-1),
                              np.zeros(1, np.uint8), K.DIFF, diff.shape[1], cut, True)
    hulls = [pts[hull[(hull_ends[i - 1] if i else 0):hull_ends[i]]] for i in sel]
    want, counts = _edge_reference(hulls, diff, cut)
    assert np.diff(np.r_[0, ends]).tolist() == list(counts)
    assert np.allclose(got, want, rtol=0, atol=1e-12)


@settings(max_examples=60, deadline=None)
@given(st.integers(0, 10**6), st.integers(3, 60))
def test_minimum_area_rectangle_of_points_is_opencvs(seed, n):
    rng = np.random.default_rng(seed)
    pts = (rng.normal(0, 1, (n, 2)) * rng.uniform(1, 40, 2)).astype(np.float32)
    idx = np.empty(2 * n + 1, np.int64)
    k = K.convex_hull(pts, idx)
    assert sorted(map(tuple, pts[idx[:k]].tolist())) == \
        sorted(map(tuple, cv2.convexHull(pts).reshape(-1, 2).tolist()))
    cu, cv, angle, w, h = K.min_rect(pts, idx, k, 0.0)
    (_, _), (ow, oh), _ = cv2.minAreaRect(pts)
    assert w * h == pytest.approx(ow * oh, rel=1e-4, abs=1e-4)
    # every point inside the rectangle
    c, s = math.cos(angle), math.sin(angle)
    d = pts.astype(float) - (cu, cv)
    assert np.all(np.abs(d @ (c, s)) <= w / 2 + 1e-4)
    assert np.all(np.abs(d @ (-s, c)) <= h / 2 + 1e-4)


def _run(code: str, **env: str) -> str:
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         env={**os.environ, **env}, timeout=300, check=True)
    return out.stdout


def test_commands_that_never_locate_do_not_import_numba():
    code = ("import sys, contextlib, io\n"
            "from feeder_bt.cli.main import main\n"
            "with contextlib.suppress(SystemExit), contextlib.redirect_stdout(io.StringIO()):\n"
            "    main(['--help'])\n"
            "import feeder_bt.vision.locator, feeder_bt.vision.pixels\n"
            "print('numba' in sys.modules)\n")
    assert _run(code).strip() == "False"


@pytest.mark.soak          # minutes of CPU: three cold compiles at once on two cores (70 s)
def test_kernels_compile_into_a_fresh_cache_from_several_processes_at_once(tmp_path):
    code = "from feeder_bt.vision.jit import warm; warm(); print('ok')"
    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path)}
    procs = [subprocess.Popen([sys.executable, "-c", code], env=env, stdout=subprocess.PIPE,
                              stderr=subprocess.PIPE, text=True) for _ in range(3)]
    for p in procs:
        out, err = p.communicate(timeout=600)
        assert p.returncode == 0, err
        assert out.strip() == "ok"
        assert err.count("compiling the locator's kernels") == 1, err      # said once
    assert any(f.suffix == ".nbi" for f in tmp_path.rglob("*"))
    back = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True,
                          text=True, timeout=300, check=True)                # read back
    assert back.stdout.strip() == "ok" and "compiling" not in back.stderr


def test_a_kernel_with_nowhere_to_cache_is_compiled_in_memory():
    # numba refuses cache=True where it finds no writable cache directory (here: code with
    # no source file); the kernels' decorator then compiles without a cache
    from feeder_bt.vision import kernels as mod
    scope: dict = {}
    exec("def twice(x):\n    return 2 * x\n", scope)
    assert mod._jit(scope["twice"])(21) == 42


def test_a_compile_says_why_on_stderr_once(monkeypatch):
    # a fresh install compiles the kernels for 13-40 s before anything else is on the
    # screen: a line says so when numba starts compiling (here two compiles: one line)
    from numba.core import event

    from feeder_bt.vision import jit
    said: list[str] = []

    def fake_print(*args, **kw):
        said.append(" ".join(args))
        assert kw.get("file") is sys.stderr

    class CompilingKernels:
        @staticmethod
        def warm():
            for _ in range(2):
                with event.trigger_event("numba:compile", data={}):
                    pass

    monkeypatch.setattr(jit, "print", fake_print, raising=False)
    monkeypatch.setattr(jit, "_mod", CompilingKernels)
    jit.warm()
    assert said == [jit.NOTICE]


def test_a_slow_load_from_the_cache_says_nothing(monkeypatch):
    # loading the cache took 1.01-1.13 s on a busy machine and the old timer (1 s) said
    # "compiling": only a compile says so now, however long a load takes
    from feeder_bt.vision import jit
    said: list[str] = []
    loaded = threading.Event()

    class LoadingKernels:
        @staticmethod
        def warm():
            loaded.wait(2.0)            # a load that takes longer than the old notice's 1 s

    monkeypatch.setattr(jit, "print", lambda *a, **k: said.append(a), raising=False)
    monkeypatch.setattr(jit, "_mod", LoadingKernels)
    jit.warm()
    assert said == []


def test_kernels_loaded_from_the_cache_say_nothing(monkeypatch):
    from feeder_bt.vision import jit
    said: list[str] = []
    monkeypatch.setattr(jit, "print", lambda *a, **k: said.append(a), raising=False)
    jit.warm()
    assert said == []


def test_contours_over_one_array_are_opencvs_contours_as_views():
    from feeder_bt.vision.chains import Contours
    mask = _mask(7)
    want, _ = cv2.findContours(mask, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    pts = np.concatenate(want).reshape(-1, 2)
    got = Contours(pts, np.array([len(c) for c in want], dtype=np.int64))
    assert len(got) == len(want) > 1
    assert all(np.array_equal(g, w) for g, w in zip(got, want, strict=True))
    assert np.array_equal(got[-1], want[-1]) and len(got[1:]) == len(want) - 1
    assert np.shares_memory(got[0], pts)              # a view, not a copy
    with pytest.raises(IndexError):
        got[len(want)]
