"""Vision time per frame: our recipe against a scikit-image and an OpenCV blob-detector pipeline.

    python benchmarks/vision_bench.py [--frames 200] [--repeats 5] [--scenarios lenses squares]
                                      [--baseline OLD_LOCATOR.py]

The frames are the ones the simulated camera grabs in a short fast run of each scenario
(``feeder render``'s ``render_frames``: 640 x 484, noise, blur, vignetting, touching parts,
parts cut by the image border), with the simulator's ground truth kept for scoring only.
Three pipelines (four with ``--baseline``) see the same frames and the same golden image:

* ``ours``: ``feeder_bt.vision.locator.Locator`` with the scenario's recipe.
* ``skimage``: golden-image subtraction in numpy, ``skimage.filters`` threshold (the
  recipe's method and level), ``skimage.morphology`` opening and closing (the recipe's
  sizes), ``skimage.measure.label`` + ``regionprops`` (area, perimeter, centroid,
  orientation and the other features the recipe's classes range over), then the recipe's
  own feature-box classification, border and size rejection. Faces of chiral parts come
  from the same cut-corner rule as ours, applied to the region's sub-pixel outline from
  ``skimage.measure.find_contours``.
* ``blob``: golden-image subtraction, then ``cv2.SimpleBlobDetector`` at the recipe's
  level, one detector per distinct set of class ranges, its area / circularity / inertia
  filters set from the recipe's area / circularity / aspect ranges (converted to the
  detector's own measures, see ``BlobPipeline``). It cannot tell the faces of a chiral
  part apart: its answers there name the part only.
* ``baseline`` (only with ``--baseline FILE``): another version of ``locator.py`` (e.g. an
  older one, ``git show REV:feeder_bt/vision/locator.py > old.py``), checked and timed
  alongside ours, so a before/after comparison shares the frames and the machine's mood.

First the answers are checked: every pipeline's parts are matched to the truth's whole,
singulated parts and to ours by position (within 2 mm): matched / missed / extra, and the
class agreement. The run fails if a pipeline agrees with the truth or with ours on fewer
than ``--min-agreement`` of the parts. Then each pipeline is timed on every frame,
``--repeats`` times, the pipelines taking turns frame by frame so machine load hits all
alike: p50 / p99 ms per frame, the median over repeats (and the spread of the p50s).
Then ours and the detector are timed again taking turns without the others
(``timing_ours_and_blob_alone``): between two of their frames no scikit-image frame
(about 20 ms of other work) has emptied the caches. Last, what those emptied caches cost
each (``first_and_second_call``): after a scikit-image frame, ours and the detector (in
turn, which first alternating frame by frame) each take the frame twice in a row; the
first call finds the caches as the three-way timing does, the second finds them warm.

scikit-image is an optional extra: ``pip install -e '.[bench]'`` (or
``pip install 'scikit-image>=0.22'``).
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import math
import platform
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from feeder_bt.cli.render_cmd import render_frames  # noqa: E402
from feeder_bt.config import load_scenario  # noqa: E402
from feeder_bt.core.geometry import place_outline, pose_outline  # noqa: E402
from feeder_bt.core.model import PartSpec, VisionRecipe  # noqa: E402
from feeder_bt.sim.render import Renderer  # noqa: E402
from feeder_bt.vision.locator import Locator  # noqa: E402
from feeder_bt.vision.pixels import Calibration  # noqa: E402

try:
    import skimage
    from scipy.spatial import ConvexHull  # a scikit-image dependency
    from skimage import filters as sk_filters
    from skimage import measure as sk_measure
    from skimage import morphology as sk_morph
except ImportError:                                   # the optional ``bench`` extra
    skimage = None

MATCH_MM = 2.0
# An 8-connected pixel chain is on average this much longer than the edge it follows
# (the mean of cos t + (sqrt 2 - 1) sin t over t in [0, 45 deg]): the blob detector's
# circularity is measured on that chain, so the recipe's range is scaled by 1 / STAIR².
STAIR = 4.0 / math.pi * (math.sqrt(2.0) / 2.0 - (math.sqrt(2.0) - 1.0) * math.sqrt(2.0) / 2.0
                         + (math.sqrt(2.0) - 1.0))

Answer = tuple[float, float, str, str | None]        # x_mm, y_mm, part, pose (None: unknown)


# ---------------------------------------------------------------------------- pipelines


class Ours:
    """The project's locator: the answers are its accepted parts."""

    name = "ours"

    def __init__(self, recipe: VisionRecipe, parts: dict[str, PartSpec], cal: Calibration,
                 golden: np.ndarray) -> None:
        self.locator = Locator(recipe, parts, cal)
        self.locator.set_golden(golden)

    def __call__(self, img: np.ndarray) -> list[Answer]:
        return [(d.x_mm, d.y_mm, d.part or "", d.pose) for d in self.locator.locate(img).parts]


class Baseline(Ours):
    """Another version of ``feeder_bt/vision/locator.py`` (``--baseline``), run as ours is."""

    name = "baseline"
    path: Path | None = None

    def __init__(self, recipe: VisionRecipe, parts: dict[str, PartSpec], cal: Calibration,
                 golden: np.ndarray) -> None:
        # a sibling module of feeder_bt.vision.locator, so its relative imports resolve
        spec = importlib.util.spec_from_file_location("feeder_bt.vision._baseline_locator",
                                                      self.path)
        module = importlib.util.module_from_spec(spec)
        sys.modules[spec.name] = module
        spec.loader.exec_module(module)
        self.locator = module.Locator(recipe, parts, cal)
        self.locator.set_golden(golden)


class SkimagePipeline:
    """The recipe done with scikit-image: threshold, morphology, label, regionprops."""

    name = "skimage"

    def __init__(self, recipe: VisionRecipe, parts: dict[str, PartSpec], cal: Calibration,
                 golden: np.ndarray) -> None:
        self.recipe, self.cal = recipe, cal
        self.golden = golden.astype(np.int16)
        m = recipe.morphology
        self.open_fp = sk_morph.disk(m.open_px // 2) if m.open_px > 1 else None
        self.close_fp = sk_morph.disk(m.close_px // 2) if m.close_px > 1 else None
        self.needed = {name for cls in recipe.classes for name in cls.ranges}
        # the model signatures of chiral parts (the same cut-corner rule as ours)
        self.faces = Locator(recipe, parts, cal)

    def _features(self, r, s: float, s2: float) -> dict[str, float]:
        """Only the features the recipe's classes range over (regionprops is lazy)."""
        area = float(r.area)
        out: dict[str, float] = {"area_mm2": area * s2}
        for name in self.needed - {"area_mm2"}:
            if name in ("perimeter_mm", "circularity"):
                p = float(r.perimeter)
                out["perimeter_mm"] = p * s
                out["circularity"] = 4 * math.pi * area / (p * p) if p > 0 else 0.0
            elif name == "aspect":
                minor = float(r.axis_minor_length)
                out[name] = float(r.axis_major_length) / minor if minor > 0 else 0.0
            elif name == "rectangularity":
                out[name] = area / _min_rect_area(r.coords)
            elif name == "solidity":
                out[name] = float(r.solidity)
            elif name in ("hu1", "hu2"):
                hu = r.moments_hu
                out["hu1"], out["hu2"] = float(hu[0]), float(hu[1])
        return out

    def __call__(self, img: np.ndarray) -> list[Answer]:
        rec = self.recipe
        diff = np.clip(self.golden - img, 0, 255).astype(np.uint8)
        th = rec.threshold
        if th.method == "fixed":
            mask = diff > math.floor(th.value)
            level = float(th.value)
        elif th.method == "otsu":
            level = max(float(sk_filters.threshold_otsu(diff)), float(th.value))
            mask = diff > level
        else:
            local = sk_filters.threshold_local(diff, max(3, int(th.block_px) | 1),
                                               method="mean", offset=-th.c)
            mask, level = diff > local, None
        if self.open_fp is not None:
            mask = sk_morph.opening(mask, self.open_fp)
        if self.close_fp is not None:
            mask = sk_morph.closing(mask, self.close_fp)
        h, w = mask.shape
        s, s2 = self.cal.mm_per_px, self.cal.mm2_per_px2
        min_px = rec.min_area_mm2 / s2
        out: list[Answer] = []
        for r in sk_measure.regionprops(sk_measure.label(mask, connectivity=2)):
            r0, c0, r1, c1 = r.bbox
            if (r1 - r0) * (c1 - c0) < min_px * 0.5:
                continue
            if r0 <= 0 or c0 <= 0 or r1 >= h or c1 >= w or r.area * s2 < rec.min_area_mm2:
                continue                                  # touches the border / too small
            feats = self._features(r, s, s2)
            chosen = self._classify(feats, diff, level, r.bbox)
            if chosen is not None:
                v, u = r.centroid
                x, y = self.cal.px_to_mm(np.array([[u, v]]))[0]
                out.append((float(x), float(y), chosen[0], chosen[1]))
        return out

    def _classify(self, feats: dict[str, float], diff: np.ndarray, level: float | None,
                  bbox: tuple[int, int, int, int]) -> tuple[str, str] | None:
        face: tuple[float, bool] | None | bool = False      # False: not looked at yet
        for cls in self.recipe.classes:
            if not all(lo <= feats.get(k, math.nan) <= hi for k, (lo, hi) in cls.ranges.items()):
                continue
            sig = self.faces._signatures.get(cls.part)
            if cls.mirrored is None or sig is None:
                return cls.part, cls.pose
            if face is False:
                face = self._face(sig, diff, level, bbox)
            if face is not None and face[1] == cls.mirrored:
                return cls.part, cls.pose
        return None

    def _face(self, sig, diff: np.ndarray, level: float | None,
              bbox: tuple[int, int, int, int]) -> tuple[float, bool] | None:
        """Angle and face from the region's sub-pixel outline (marching squares)."""
        if level is None:
            return None
        r0, c0, r1, c1 = bbox
        r0, c0 = max(r0 - 2, 0), max(c0 - 2, 0)
        r1, c1 = min(r1 + 2, diff.shape[0]), min(c1 + 2, diff.shape[1])
        cs = sk_measure.find_contours(diff[r0:r1, c0:c1].astype(np.float32), level)
        if not cs:
            return None
        rc = max(cs, key=len)
        uv = np.stack([rc[:, 1] + c0, rc[:, 0] + r0], axis=1)
        return Locator._cut_corner(sig, self.cal.px_to_mm(uv))


def _min_rect_area(coords: np.ndarray) -> float:
    """Area of the minimum-area rectangle around pixel centres, grown to the pixels'
    edges (width + 1, height + 1), the same convention as ours: over the hull's edges."""
    pts = coords[:, ::-1].astype(float)
    try:
        hull = pts[ConvexHull(pts).vertices]
    except Exception:                                         # degenerate (a line of pixels)
        return float(len(pts))
    e = np.roll(hull, -1, axis=0) - hull
    a = np.arctan2(e[:, 1], e[:, 0])
    c, s = np.cos(a)[:, None], np.sin(a)[:, None]
    px = hull[:, 0][None, :] * c + hull[:, 1][None, :] * s
    py = -hull[:, 0][None, :] * s + hull[:, 1][None, :] * c
    areas = (np.ptp(px, axis=1) + 1.0) * (np.ptp(py, axis=1) + 1.0)
    return float(areas.min())


@dataclass
class _Detector:
    detector: cv2.SimpleBlobDetector
    part: str
    pose: str | None            # None: the classes it stands for differ only in face


class BlobPipeline:
    """The recipe's ranges as ``cv2.SimpleBlobDetector`` filters.

    The detector measures area through the centres of the boundary pixels (the pixel count
    less about half the perimeter: the recipe's area range is moved by half the perimeter
    of a disc of that area) and circularity on the 8-connected pixel chain (the recipe's
    range scaled by 1 / ``STAIR``²); the recipe's aspect range becomes the detector's
    inertia ratio (1 / aspect²). Rectangularity, solidity and Hu ranges have no detector
    filter and are left out. The detector thresholds the difference image itself at the
    recipe's level (Otsu: the level OpenCV finds, floored at the recipe's value) and has
    no morphology; blobs closer to the border than their radius are dropped, as a stand-in
    for the recipe's border rule.
    """

    name = "blob"

    def __init__(self, recipe: VisionRecipe, parts: dict[str, PartSpec], cal: Calibration,
                 golden: np.ndarray) -> None:
        self.recipe, self.cal, self.golden = recipe, cal, golden
        groups: dict[tuple, list] = {}
        for cls in recipe.classes:
            groups.setdefault(tuple(sorted(cls.ranges.items())), []).append(cls)
        self.specs = []
        for ranges, classes in groups.items():
            poses = {c.pose for c in classes}
            self.specs.append((dict(ranges), classes[0].part,
                               classes[0].pose if len(poses) == 1 else None))
        self._fixed: list[_Detector] | None = None
        if recipe.threshold.method == "fixed":
            self._fixed = self._detectors(int(math.floor(recipe.threshold.value)))

    def _detectors(self, level: int) -> list[_Detector]:
        s2 = self.cal.mm2_per_px2
        out = []
        for ranges, part, pose in self.specs:
            p = cv2.SimpleBlobDetector_Params()
            p.minThreshold, p.maxThreshold, p.thresholdStep = level, level + 1, 1
            p.minRepeatability, p.minDistBetweenBlobs = 1, 1.0
            p.filterByColor, p.blobColor = True, 255
            lo, hi = ranges.get("area_mm2", (self.recipe.min_area_mm2, 1e9))
            lo, hi = lo / s2, hi / s2
            p.filterByArea = True
            p.minArea = lo - math.sqrt(math.pi * lo)        # less half a disc's perimeter
            p.maxArea = hi - math.sqrt(math.pi * hi)
            p.filterByCircularity = "circularity" in ranges
            if p.filterByCircularity:
                c_lo, c_hi = ranges["circularity"]
                p.minCircularity, p.maxCircularity = c_lo / STAIR ** 2, c_hi / STAIR ** 2
            p.filterByInertia = "aspect" in ranges
            if p.filterByInertia:
                a_lo, a_hi = ranges["aspect"]
                p.minInertiaRatio, p.maxInertiaRatio = 1.0 / a_hi ** 2, 1.0 / a_lo ** 2
            p.filterByConvexity = False
            out.append(_Detector(cv2.SimpleBlobDetector_create(p), part, pose))
        return out

    def __call__(self, img: np.ndarray) -> list[Answer]:
        diff = cv2.subtract(self.golden, img)
        dets = self._fixed
        if dets is None:                         # Otsu: the level varies frame to frame
            level, _ = cv2.threshold(diff, 0, 255, cv2.THRESH_BINARY | cv2.THRESH_OTSU)
            dets = self._detectors(int(max(level, self.recipe.threshold.value)))
        h, w = diff.shape
        out: list[Answer] = []
        for d in dets:
            for kp in d.detector.detect(diff):
                u, v = kp.pt
                r = kp.size / 2.0 + 1.0
                if u < r or v < r or u > w - 1 - r or v > h - 1 - r:
                    continue
                x, y = self.cal.px_to_mm(np.array([[u, v]]))[0]
                out.append((float(x), float(y), d.part, d.pose))
        return out


# ---------------------------------------------------------------------------- scoring


def _match(a: list[Answer], b: list[Answer]) -> list[tuple[int, int]]:
    """Pairs (i, j) of a[i] and b[j] within MATCH_MM, nearest pairs first, each used once."""
    pairs = sorted((math.hypot(p[0] - q[0], p[1] - q[1]), i, j)
                   for i, p in enumerate(a) for j, q in enumerate(b))
    used_a, used_b, out = set(), set(), []
    for dist, i, j in pairs:
        if dist > MATCH_MM:
            break
        if i not in used_a and j not in used_b:
            used_a.add(i)
            used_b.add(j)
            out.append((i, j))
    return out


def _same_class(p: Answer, q: Answer) -> bool:
    return p[2] == q[2] and (p[3] is None or q[3] is None or p[3] == q[3])


def _score(found: list[list[Answer]], ref: list[list[Answer]]) -> dict[str, float]:
    """matched / missed (in ref only) / extra (in found only) / class agreement / agreement
    = matched / (matched + missed + extra)."""
    matched = missed = extra = same = 0
    for f, r in zip(found, ref, strict=True):
        pairs = _match(r, f)
        matched += len(pairs)
        missed += len(r) - len(pairs)
        extra += len(f) - len(pairs)
        same += sum(_same_class(r[i], f[j]) for i, j in pairs)
    total = matched + missed + extra
    return {"matched": matched, "missed": missed, "extra": extra,
            "class_agreement": round(same / matched, 4) if matched else 0.0,
            "agreement": round(matched / total, 4) if total else 1.0}


def _truth_answers(truth: list[dict]) -> list[list[Answer]]:
    """What a locator should find: parts wholly inside the image and not touching another."""
    return [[(p["x_mm"], p["y_mm"], p["type"], p["pose"]) for p in t["parts"]
             if p["whole"] and p["singulated"]] for t in truth]


def _pct(v: list[float], q: float) -> float:
    return round(float(np.percentile(v, q)), 4)


def _time(pipes: list[Callable[[np.ndarray], list[Answer]]], frames: list[np.ndarray],
          repeats: int) -> dict[str, dict]:
    """p50 / p99 ms per frame per pipeline, pipelines taking turns frame by frame."""
    per: dict[str, dict[str, list[float]]] = {p.name: {"p50": [], "p99": []} for p in pipes}
    for rep in range(repeats):
        ms: dict[str, list[float]] = {p.name: [] for p in pipes}
        for i, img in enumerate(frames):
            k = (i + rep) % len(pipes)
            for p in pipes[k:] + pipes[:k]:
                t0 = time.perf_counter()
                p(img)
                ms[p.name].append((time.perf_counter() - t0) * 1e3)
        for name, v in ms.items():
            per[name]["p50"].append(_pct(v, 50))
            per[name]["p99"].append(_pct(v, 99))
    return {name: {"p50_ms": round(float(np.median(v["p50"])), 4),
                   "p99_ms": round(float(np.median(v["p99"])), 4),
                   "p50_spread_ms": [min(v["p50"]), max(v["p50"])]}
            for name, v in per.items()}


def _first_and_second(pipes: list[Callable[[np.ndarray], list[Answer]]],
                       frames: list[np.ndarray], repeats: int) -> dict[str, dict]:
    """p50 ms of each pipeline's first and second call on a frame, right after a
    scikit-image frame (``pipes[0]``) each: what cold caches cost it (the median over
    repeats)."""
    warmup, timed = pipes[0], pipes[1:]
    per: dict[str, dict[str, list[float]]] = {
        p.name: {"first": [], "second": []} for p in timed}
    for rep in range(repeats):
        ms: dict[str, dict[str, list[float]]] = {
            p.name: {"first": [], "second": []} for p in timed}
        for i, img in enumerate(frames):
            k = (i + rep) % len(timed)
            for p in timed[k:] + timed[:k]:
                warmup(img)
                t0 = time.perf_counter()
                p(img)
                t1 = time.perf_counter()
                p(img)
                t2 = time.perf_counter()
                ms[p.name]["first"].append((t1 - t0) * 1e3)
                ms[p.name]["second"].append((t2 - t1) * 1e3)
        for name, v in ms.items():
            for which in ("first", "second"):
                per[name][which].append(_pct(v[which], 50))
    return {name: {f"{which}_p50_ms": round(float(np.median(v[which])), 4)
                   for which in ("first", "second")} for name, v in per.items()}


def _render_ms(name: str, scenario, cam, truth: list[dict], seed: int) -> dict[str, float]:
    """The simulated camera's renderer on the same scenes (outlines from the truth)."""
    renderer = Renderer(cam)
    rng = np.random.default_rng(seed)
    ms = []
    for t in truth:
        outlines = [place_outline(pose_outline(scenario.parts[p["type"]], p["pose"]),
                                  p["x_mm"], p["y_mm"], p["angle_deg"]) for p in t["parts"]]
        t0 = time.perf_counter()
        renderer.render(outlines, rng)
        ms.append((time.perf_counter() - t0) * 1e3)
    return {"p50_ms": _pct(ms, 50), "p99_ms": _pct(ms, 99)}


def bench_scenario(name: str, n_frames: int, repeats: int, seed: int,
                   min_agreement: float) -> dict:
    path = ROOT / "scenarios" / f"{name}.yaml"
    scenario, cell = load_scenario(path)
    cam = cell.camera
    cal = Calibration(cam.calibration)
    got = render_frames(str(path), n_frames, seed)
    kinds = [Ours, SkimagePipeline, BlobPipeline] + ([Baseline] if Baseline.path else [])
    pipes = [kind(scenario.vision, scenario.parts, cal, got.golden) for kind in kinds]
    truth = _truth_answers(got.truth)
    answers = {p.name: [p(img) for img in got.frames] for p in pipes}
    check = {p.name: {"vs_truth": _score(answers[p.name], truth),
                      "vs_ours": _score(answers[p.name], answers["ours"])} for p in pipes}
    for pname, c in check.items():
        for ref, sc in c.items():
            if sc["agreement"] < min_agreement:
                raise SystemExit(f"{name}: {pname} {ref} agreement {sc['agreement']} < "
                                 f"{min_agreement}: the pipelines do not give the same "
                                 f"answers, timing them would compare different work")
    timing = _time(pipes, got.frames, repeats)
    ours = timing["ours"]["p50_ms"]
    # ours and the detector alone, taking turns: no scikit-image frame (about 20 ms of
    # other work) between them to empty the caches (docs/performance.md, third round)
    pair = _time([p for p in pipes if p.name in ("ours", "blob")], got.frames, repeats)
    by_name = {p.name: p for p in pipes}
    twice = _first_and_second([by_name["skimage"], by_name["ours"], by_name["blob"]],
                              got.frames, repeats)
    return {
        "frames": len(got.frames), "image_px": [cam.width_px, cam.height_px],
        "truth_parts": sum(len(t) for t in truth),
        "parts_in_view": sum(len(t["parts"]) for t in got.truth),
        "answers": check, "timing": timing, "timing_ours_and_blob_alone": pair,
        "first_and_second_call": twice,
        "ours_faster_than_peers": all(ours < v["p50_ms"] for k, v in timing.items()
                                      if k not in ("ours", "baseline")),
        "render": _render_ms(name, scenario, cam, got.truth, seed),
    }


def main(argv: list[str] | None = None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--frames", type=int, default=200, help="frames per scenario")
    ap.add_argument("--repeats", type=int, default=5, help="timing passes over the frames")
    ap.add_argument("--scenarios", nargs="*", default=["lenses", "squares"])
    ap.add_argument("--seed", type=int, default=1, help="seed of the simulated cell")
    ap.add_argument("--min-agreement", type=float, default=0.95,
                    help="fail below this matched / (matched + missed + extra)")
    ap.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results" / "vision.json")
    ap.add_argument("--baseline", type=Path, default=None,
                    help="another locator.py to check and time alongside ours")
    args = ap.parse_args(argv)
    Baseline.path = args.baseline
    if skimage is None:
        raise SystemExit("vision_bench needs scikit-image for its peer pipeline: "
                         "pip install -e '.[bench]'   (or: pip install 'scikit-image>=0.22')")
    report = {
        "benchmark": "vision",
        "method": "frames from render_frames (the simulated camera's grabs); answers matched "
                  f"by position within {MATCH_MM} mm; pipelines take turns frame by frame; "
                  "p50/p99 per repeat, median over repeats",
        "repeats": args.repeats, "seed": args.seed,
        "scenarios": {name: bench_scenario(name, args.frames, args.repeats, args.seed,
                                           args.min_agreement)
                      for name in args.scenarios},
        "versions": {"python": platform.python_version(), "numpy": np.__version__,
                     "opencv": cv2.__version__, "scikit-image": skimage.__version__},
        "machine": platform.machine(),
    }
    return write_report(report, args.out)


def write_report(report: dict, out: Path) -> dict:
    """The benchmark's JSON to ``out`` and to the terminal (``vision_floor`` too)."""
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(report, indent=2) + "\n")
    print(json.dumps(report, indent=2))
    return report


if __name__ == "__main__":
    main()
