"""``feeder teach``: a scenario learnt from labelled photos instead of written by hand.

From sample images and what is in them (``tuning.labels``) it learns, in this order:

1. the segmentation: every candidate threshold (fixed levels, Otsu, adaptive, each against
   the raw image or a golden image made as the median of the frames; parts darker or
   lighter than the belt), each with every opening and closing of ``MORPH_PX`` (for
   --part folders alone, which have no boxes to judge an outline by, both a 25th of the
   parts' size), is scored by how well it separates the labelled parts — each label box
   holding exactly one whole blob that fills it, no blob outside every box — and the
   best kept (on a tie, the one with the smaller kernels, then the simpler threshold);
2. each class's feature ranges (``tuning.ranges``: the samples' spread plus a margin), with
   the features that keep classes apart: area always, a shape feature that shuts out
   touching pairs, and for every pair of classes whose boxes would overlap the feature
   whose sample ranges are furthest apart (an outline feature, or failing those the
   frame's grey under the blob: ``grey_mean``, ``grey_std``); a pair that no feature
   separates is an error naming both classes. Where two classes are apart on a feature, each range reaches
   halfway to the other (the nearer class wins), elsewhere its margin; the area's top
   reaches halfway to two of the class touching where no class is nearer;
3. each pose's outline with its holes, in mm through the cell's camera scale: the samples'
   outlines turned onto one another and the pixels most of them cover (a median
   silhouette); its rotational and mirror symmetry; a pick point on material, as far from
   every edge and hole as the outline allows.

The scenario is written as YAML a person reads and edits (``write_scenario``), with
comments saying what was learnt from how many samples; ``feeder check`` takes it and
``feeder locate`` runs it. Whether it cuts touching parts apart (``split_touching``) is
decided by ``feeder teach`` (cli.teach_cmd), which scores the written scenario both ways
on the teaching images through the locator ``feeder run`` builds (``Taught.split``).
Nothing here reads the ground truth of a held-out image: ``tuning.evaluate`` scores the
written scenario on those.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass, field, replace
from pathlib import Path

import cv2
import numpy as np

from feeder_bt.config import load_cell
from feeder_bt.core.images import BadInput, write_image
from feeder_bt.core.model import CellSpec, Morphology, Threshold, VisionRecipe
from feeder_bt.tuning.labels import Box, Sample
from feeder_bt.tuning.ranges import PREFERRED, fmt, round_sig, spread, widen
from feeder_bt.vision.blobs import Blob
from feeder_bt.vision.locator import Locator
from feeder_bt.vision.pixels import Calibration
from feeder_bt.vision.segment import otsu_level, to_grey

MATCH_IOU = 0.5            # a blob is a label's part when its box overlaps the label's this much
SPECK = 0.25               # blobs under this fraction of the smallest part's area are specks
HOLE = 0.02                # holes under this fraction of the smallest part's area are not counted
OUTLIER_AREA = 0.30        # a --part folder's blob this far from the median area: not one part
SYMMETRIC_IOU = 0.92       # an outline this alike turned (or mirrored) is symmetric
GRID = 96                  # the outline raster's cells across the largest sample
ALIGN_STEP_DEG = 4.0       # the coarse turn search aligning samples' outlines
MORPH_PX = (0, 3, 5, 7)    # the opening and closing kernels tried (px; 0: none)
#: Shape features that tell a whole part from touching parts, steadiest chosen per class.
SHAPE = ("solidity", "circularity", "rectangularity", "aspect")
#: Pixel features tried when no outline feature separates two classes (steadier first).
GREY = ("grey_mean", "grey_std")


Cls = tuple[str, str]


@dataclass
class Segmentation:
    """One candidate way of finding blobs, and how well it separated the labelled parts."""

    name: str
    recipe: VisionRecipe
    golden: np.ndarray | None = None
    good: int = 0              # labels with exactly one blob that fills them
    labels: int = 0            # labels scored (those cut by the image's edge are not)
    stray: int = 0             # whole blobs in no label's box
    fit: float = 0.0           # mean overlap of the good blobs with their boxes

    @property
    def score(self) -> float:
        """The share of labels found alone, less a share for each stray blob."""
        return self.good / max(self.labels + self.stray, 1)


@dataclass
class Measured:
    """One sample part as the chosen segmentation measured it."""

    features: dict[str, float]
    outer_mm: np.ndarray                  # (n, 2) about the blob's centroid
    holes_mm: list[np.ndarray]


@dataclass
class Outline:
    """A pose's learnt silhouette (mm, part frame: origin at its area centroid)."""

    points_mm: list[tuple[float, float]]
    holes_mm: list[list[tuple[float, float]]]
    symmetry: int
    mirror_symmetric: bool
    grips_mm: list[tuple[float, float]]
    cup_radius_mm: float
    samples: int


@dataclass
class Taught:
    """What ``teach`` learnt: the recipe, the classes and outlines, and how."""

    segmentation: Segmentation
    recipe: VisionRecipe
    ranges: dict[Cls, dict[str, tuple[float, float]]]
    samples: dict[Cls, list[Measured]]
    outlines: dict[Cls, Outline]
    separated: list[tuple[Cls, Cls, str]] = field(default_factory=list)
    tried: int = 0
    # the teaching images' F1 without and with ``split_touching`` (None: not tried)
    split: tuple[float, float] | None = None


# ---------------------------------------------------------------------------- segmentation


def _odd(v: float) -> int:
    return max(3, int(round(v)) | 1)


def candidates(samples: list[Sample], min_area_mm2: float, min_hole_mm2: float,
               size_px: float) -> list[Segmentation]:
    """Every segmentation worth trying on these images, simplest first."""
    greys = [to_grey(s.image) for s in samples]
    out: list[Segmentation] = []

    def recipe(fg: str, th: Threshold, golden: bool) -> VisionRecipe:
        return VisionRecipe(backlight=False, golden_image=golden, foreground=fg, threshold=th,
                            morphology=Morphology(), min_area_mm2=min_area_mm2,
                            min_hole_mm2=min_hole_mm2,
                            classes=[], orientation="none", check_clearance=False)

    same = len({g.shape for g in greys}) == 1 and len(greys) >= 3
    golden = np.median(np.stack(greys), axis=0).astype(np.uint8) if same else None
    for fg in ("dark", "light"):
        bright = [g if fg == "light" else cv2.bitwise_not(g) for g in greys]
        level = float(np.median([otsu_level(b) for b in bright]))
        out.append(Segmentation(f"otsu, parts {fg}er than the background",
                                recipe(fg, Threshold(method="otsu", value=5.0), False)))
        for f in (0.7, 0.85, 1.0, 1.15, 1.3):
            v = round(level * f)
            out.append(Segmentation(f"fixed level {v}, parts {fg}er than the background",
                                    recipe(fg, Threshold(method="fixed", value=v), False)))
        for kb in (0.75, 1.5, 3.0):
            for c in (-5.0, -10.0, -20.0):
                b = _odd(size_px * kb)
                out.append(Segmentation(
                    f"adaptive, {b} px blocks, c {c:g}, parts {fg}er than the background",
                    recipe(fg, Threshold(method="adaptive", block_px=b, c=c), False)))
        if golden is not None:
            diffs = [cv2.subtract(g, golden) if fg == "light" else cv2.subtract(golden, g)
                     for g in greys]
            level = float(np.median([otsu_level(d) for d in diffs]))
            out.append(Segmentation(
                f"otsu against the median of the frames, parts {fg}er",
                recipe(fg, Threshold(method="otsu", value=5.0), True), golden))
            for f in (0.5, 0.75, 1.0, 1.25):
                v = max(1, round(level * f))
                out.append(Segmentation(
                    f"fixed level {v} against the median of the frames, parts {fg}er",
                    recipe(fg, Threshold(method="fixed", value=v), True), golden))
    # each threshold with every opening and closing: a closing that mends a ragged
    # outline also joins parts a few pixels apart, so the labels' boxes choose. Without
    # boxes (--part folders only) nothing tells a ragged outline from a whole one: an
    # opening and a closing of a 25th of the parts' size
    if any(s.part is None for s in samples):
        morphs = sorted(itertools.product(MORPH_PX, MORPH_PX),
                        key=lambda ok: (ok[0] + ok[1], ok))
    else:
        morphs = [(_odd(size_px / 25), _odd(size_px / 25))]
    return [Segmentation(f"{c.name}, {_morph_name(o, k)}",
                         replace(c.recipe, morphology=Morphology(open_px=o, close_px=k)),
                         c.golden)
            for c in out for o, k in morphs]


def _morph_name(open_px: int, close_px: int) -> str:
    if not open_px and not close_px:
        return "no morphology"
    return " and ".join(f"{what} {px} px" for what, px in (("opened", open_px),
                                                            ("closed", close_px)) if px)


def _box_iou(box: Box, b: tuple[int, int, int, int]) -> float:
    u, v, w, h = b
    ix = max(0.0, min(box.x + box.w, u + w) - max(box.x, u))
    iy = max(0.0, min(box.y + box.h, v + h) - max(box.y, v))
    inter = ix * iy
    return inter / (box.w * box.h + w * h - inter)


def match(sample: Sample, blobs: list[Blob]) -> tuple[dict[int, list[Blob]], list[Blob]]:
    """Each scored label's blobs (centroid in its box, boxes overlapping by ``MATCH_IOU``),
    and the whole blobs in no label's box. Labels cut by the image's edge are not scored,
    and blobs in their boxes are not strays."""
    h, w = sample.image.shape[:2]
    whole = [b for b in blobs if not b.det.reason or b.det.reason.startswith("no class")]
    found: dict[int, list[Blob]] = {}
    stray = []
    for b in whole:
        u, v = b.det.u_px, b.det.v_px
        hit = [i for i, box in enumerate(sample.boxes) if box.contains(u, v)]
        if not hit:
            stray.append(b)
        for i in hit:
            box = sample.boxes[i]
            if not box.touches_border(w, h) and _box_iou(box, b.box) >= MATCH_IOU:
                found.setdefault(i, []).append(b)
    for i, box in enumerate(sample.boxes):
        if not box.touches_border(w, h):
            found.setdefault(i, [])
    return found, stray


def _part_blobs(blobs: list[Blob]) -> tuple[list[Blob], list[Blob]]:
    """A --part folder image's whole blobs: those near the median area, and the others."""
    whole = [b for b in blobs if not b.det.reason or b.det.reason.startswith("no class")]
    if not whole:
        return [], []
    med = float(np.median([b.det.features["area_mm2"] for b in whole]))
    near = [b for b in whole if abs(b.det.features["area_mm2"] - med) <= OUTLIER_AREA * med]
    return near, [b for b in whole if b not in near]


def score(seg: Segmentation, samples: list[Sample], calibration: Calibration) -> None:
    """Fill in how well ``seg`` separates the samples' parts."""
    loc = Locator(seg.recipe, {}, calibration)
    if seg.golden is not None:
        loc.set_golden(seg.golden)
    fits = []
    for s in samples:
        blobs = loc.locate(s.image).blobs
        if s.part is not None:
            near, other = _part_blobs(blobs)
            seg.good += len(near)
            seg.labels += len(near)
            seg.stray += len(other)
            continue
        found, stray = match(s, blobs)
        seg.labels += len(found)
        seg.stray += len(stray)
        for i, bs in found.items():
            if len(bs) == 1:
                seg.good += 1
                fits.append(_box_iou(s.boxes[i], bs[0].box))
    seg.fit = float(np.mean(fits)) if fits else 0.0


def _kernels(c: Segmentation) -> int:
    """How much morphology a candidate does (on a tie, the least wins)."""
    return c.recipe.morphology.open_px + c.recipe.morphology.close_px


def choose_segmentation(samples: list[Sample], calibration: Calibration, min_area_mm2: float,
                        min_hole_mm2: float, size_px: float) -> tuple[Segmentation, int]:
    """The candidate that separates the labelled parts best (and how many were tried)."""
    cands = candidates(samples, min_area_mm2, min_hole_mm2, size_px)
    for c in cands:
        score(c, samples, calibration)
    if any(s.part is None for s in samples):
        def key(c: Segmentation) -> tuple:
            return round(c.score, 6), round(c.fit, 3), -_kernels(c), -cands.index(c)
    else:
        # --part folders only: no boxes to fill, so many blobs alike beat a few (a
        # segmentation finding three shadows of one size is not the best)
        def key(c: Segmentation) -> tuple:
            return round(c.good * c.score, 6), -_kernels(c), -cands.index(c)
    best = max(cands, key=key)
    if best.good == 0:
        raise BadInput("no segmentation finds any labelled part alone: check that the "
                       "labels' boxes are on the parts (x, y, width, height in pixels)")
    return best, len(cands)


# ---------------------------------------------------------------------------- samples


def measure(seg: Segmentation, samples: list[Sample], calibration: Calibration
            ) -> dict[Cls, list[Measured]]:
    """Each class's sample parts: the blobs the chosen segmentation found alone in a label's
    box (or, in a --part folder, near the median area), with every feature and the
    outline in mm."""
    loc = Locator(seg.recipe, {}, calibration)
    if seg.golden is not None:
        loc.set_golden(seg.golden)
    out: dict[Cls, list[Measured]] = {}
    for s in samples:
        blobs = loc.locate(s.image, all_features=True).blobs
        if s.part is not None:
            pairs = [(s.part, b) for b in _part_blobs(blobs)[0]]
        else:
            found = match(s, blobs)[0]
            pairs = [(s.boxes[i].cls, bs[0]) for i, bs in found.items() if len(bs) == 1]
        for cls, b in pairs:
            c = np.array([b.det.x_mm, b.det.y_mm])
            outer = calibration.px_to_mm(b.contour.reshape(-1, 2).astype(float)) - c
            holes = [calibration.px_to_mm(hh.reshape(-1, 2).astype(float)) - c
                     for hh in (b.holes or []) if len(hh) >= 3]
            out.setdefault(cls, []).append(Measured(dict(b.det.features), outer, holes))
    return out


# ---------------------------------------------------------------------------- classes


TRIM = 0.1                 # classes of 10+ samples: this share at each end is not their edge
POOL_MIN = 5               # classes of this many samples tell how much a class varies ...
SPREADS = 2.0              # ... and a range is at least this many of their spreads each side


def _interval(ms: list[Measured], name: str, trim: bool = False) -> tuple[float, float]:
    """The samples' range of a feature; ``trim``: without the few most extreme at each
    end (a washer whose hole a neighbour's shadow filled, a mislabelled box), so that one
    odd sample does not merge two classes."""
    v = np.array([m.features[name] for m in ms], dtype=float)
    if trim and len(v) >= 10:
        return float(np.quantile(v, TRIM)), float(np.quantile(v, 1 - TRIM))
    return float(v.min()), float(v.max())


def _apart(a: tuple[float, float], b: tuple[float, float]) -> float:
    """How far apart two sample intervals are, in units of their spans (<= 0: overlapping)."""
    gap = max(b[0] - a[1], a[0] - b[1])
    scale = max(a[1] - a[0], b[1] - b[0], 0.02 * max(abs(a[1]), abs(b[1]), 1e-9))
    return gap / scale


def learn_classes(samples: dict[Cls, list[Measured]]
                  ) -> tuple[dict[Cls, dict[str, tuple[float, float]]], list[tuple[Cls, Cls, str]]]:
    """Each class's ranges, and the pairs a feature was added to separate (see the module
    docstring). Raises ``BadInput`` naming two classes no feature separates."""
    classes = sorted(samples)
    # one shape feature for every class, the steadiest within the classes: it shuts out
    # touching parts, whatever the class, so its range is learnt from all the samples (a
    # class of a few samples would get too narrow a range of its own)
    shape = min(SHAPE, key=lambda n: float(np.mean(
        [spread([m.features for m in samples[c]], n) for c in classes])))
    pooled = [m for c in classes for m in samples[c]]
    chosen: dict[Cls, list[str]] = {c: ["area_mm2", shape] for c in classes}
    separated = []
    names = ["area_mm2", *PREFERRED]
    for i, a in enumerate(classes):
        for b in classes[i + 1:]:
            used = set(chosen[a]) | set(chosen[b])
            def apart(n: str, a: Cls = a, b: Cls = b) -> float:
                return _apart(_interval(samples[a], n, True), _interval(samples[b], n, True))

            if any(apart(n) > 0.05 for n in used):
                continue
            best = max(names, key=apart)
            d = apart(best)
            if d <= 0:
                # no outline feature: the frame's grey under the blob (brass and steel of
                # one size under a front light), the outline's first when both would do
                greys = [n for n in GREY
                         if all(n in m.features for m in samples[a] + samples[b])]
                grey = max(greys, key=apart, default=None)
                if grey is not None and apart(grey) > 0:
                    best, d = grey, apart(grey)
            if d <= 0:
                raise BadInput(
                    f"classes {'/'.join(a)} and {'/'.join(b)} overlap in every feature "
                    f"(nearest to apart: {best}); label them as one class, or add a "
                    "ruler that tells them apart (docs/scenarios.md)")
            for c in (a, b):
                if best not in chosen[c]:
                    chosen[c].append(best)
            separated.append((a, b, best))
    ranges: dict[Cls, dict[str, tuple[float, float]]] = {}
    split = {(c, f) for a, b, f in separated for c in (a, b)}
    many = [c for c in classes if len(samples[c]) >= POOL_MIN]
    pooled_spread = {n: float(np.median([spread([m.features for m in samples[c]], n)
                                         for c in many])) if many else 0.0
                     for n in [*names, *GREY]}
    for c in classes:
        r = {}
        for n in chosen[c]:
            if n == shape and (c, shape) not in split:
                r[n] = widen(list(_interval(pooled, n)))
                continue
            lo, hi = _interval(samples[c], n)
            tlo, thi = _interval(samples[c], n, True)
            # towards a class apart on this feature the range reaches halfway to it (the
            # nearer class wins, as a person sorting by eye would); elsewhere the margin
            below = [dhi for d in classes if d != c
                     for dlo, dhi in [_interval(samples[d], n, True)] if dhi < tlo]
            above = [dlo for d in classes if d != c
                     for dlo, dhi in [_interval(samples[d], n, True)] if dlo > thi]
            if n == "holes":              # a count is exact
                r[n] = (tlo if below else lo, thi if above else hi)
                continue
            wlo, whi = widen([lo, hi])
            # a class of a few samples has seen little of how its parts vary: its range
            # is at least as wide as the classes of many vary (their spread, pooled)
            mid = (lo + hi) / 2
            half = SPREADS * pooled_spread.get(n, 0.0) * abs(mid)
            wlo = min(wlo, round_sig(mid - half, math.floor))
            whi = max(whi, round_sig(mid + half, math.ceil))
            if n == "area_mm2" and 2 * tlo > thi:
                # what the area's top has to shut out is two of the class touching (at
                # least twice its smallest): with no class nearer, reach halfway to that,
                # as towards a class. A few samples show little of how large a natural
                # part grows: an oyster 15 % above the largest of eleven is still one.
                # (A class whose largest is twice its smallest keeps its margin: its
                # area cannot tell one from two.)
                above.append(2 * tlo)
            if below:
                wlo = round_sig((max(below) + tlo) / 2, math.ceil)
            if above:
                whi = round_sig((thi + min(above)) / 2, math.floor)
            r[n] = (wlo, whi)
        ranges[c] = r
    return ranges, separated


# ---------------------------------------------------------------------------- outlines


class _Raster:
    """Outlines drawn on one square grid about the part frame's origin."""

    def __init__(self, radius_mm: float) -> None:
        self.res = 2 * radius_mm / GRID
        self.size = GRID + 8
        self.half = self.size / 2

    def draw(self, m: Measured, angle_deg: float) -> np.ndarray:
        a = math.radians(angle_deg)
        rot = np.array([[math.cos(a), -math.sin(a)], [math.sin(a), math.cos(a)]])
        mask = np.zeros((self.size, self.size), np.uint8)
        cv2.fillPoly(mask, [self._px(m.outer_mm @ rot.T)], 1)
        for h in m.holes_mm:
            cv2.fillPoly(mask, [self._px(h @ rot.T)], 0)
        return mask

    def _px(self, pts: np.ndarray) -> np.ndarray:
        return np.round(pts / self.res + self.half).astype(np.int32).reshape(-1, 1, 2)

    def to_mm(self, pts: np.ndarray) -> np.ndarray:
        return (pts.reshape(-1, 2).astype(float) - self.half) * self.res


def _iou(a: np.ndarray, b: np.ndarray) -> float:
    inter = int(np.count_nonzero(a & b))
    union = int(np.count_nonzero(a | b))
    return inter / union if union else 0.0


def _turned(mask: np.ndarray, angle_deg: float, flip: bool = False) -> np.ndarray:
    c = (mask.shape[1] / 2 - 0.5, mask.shape[0] / 2 - 0.5)
    src = mask[::-1].copy() if flip else mask
    m = cv2.getRotationMatrix2D(c, angle_deg, 1.0)
    return cv2.warpAffine(src, m, mask.shape[::-1], flags=cv2.INTER_NEAREST)


def _align(r: _Raster, m: Measured, ref: np.ndarray) -> np.ndarray:
    """The sample's mask turned to best overlap ``ref`` (coarse search, then finer)."""
    best_a, best = 0.0, -1.0
    for a in np.arange(0.0, 360.0, ALIGN_STEP_DEG):
        s = _iou(r.draw(m, float(a)), ref)
        if s > best:
            best_a, best = float(a), s
    step = ALIGN_STEP_DEG / 2
    while step >= 0.5:
        for a in (best_a - step, best_a + step):
            s = _iou(r.draw(m, a), ref)
            if s > best:
                best_a, best = a, s
        step /= 2
    return r.draw(m, best_a)


def _symmetry(mask: np.ndarray) -> tuple[int, bool]:
    """Rotational symmetry (360: a disc; 1: none) and mirror symmetry of a silhouette."""
    if all(_iou(mask, _turned(mask, a)) >= SYMMETRIC_IOU for a in (23.0, 61.0, 137.0)):
        sym = 360
    else:
        sym = next((n for n in (8, 6, 5, 4, 3, 2)
                    if all(_iou(mask, _turned(mask, 360.0 * k / n)) >= SYMMETRIC_IOU
                           for k in range(1, n))), 1)
    mirror = max(_iou(mask, _turned(mask, float(a), flip=True))
                 for a in np.arange(0.0, 360.0, 2.0)) >= SYMMETRIC_IOU
    return sym, mirror


def learn_outline(ms: list[Measured]) -> Outline:
    """The median silhouette of the samples (see the module docstring)."""
    radius = max(float(np.hypot(*m.outer_mm.T).max()) for m in ms) * 1.05
    r = _Raster(radius)
    areas = [m.features["area_mm2"] for m in ms]
    ref_i = int(np.argsort(areas)[len(areas) // 2])
    ref = r.draw(ms[ref_i], 0.0)
    for _ in range(2):              # align to one sample, then to the first vote
        masks = [_align(r, m, ref) for m in ms]
        # the cells most samples cover, the vote smoothed over a cell or so: the outline
        # follows the part, not the pixel staircase of each sample
        vote = cv2.GaussianBlur(np.mean(masks, axis=0).astype(np.float32), (5, 5), 1.0)
        ref = (vote >= 0.5).astype(np.uint8)
    mom = cv2.moments(ref, binaryImage=True)
    if mom["m00"] == 0:
        raise BadInput("the samples' outlines have nothing in common")
    # recentre on the silhouette's area centroid, the part frame's origin
    dx, dy = mom["m10"] / mom["m00"] - r.half, mom["m01"] / mom["m00"] - r.half
    shift = np.float32([[1, 0, -dx], [0, 1, -dy]])
    ref = cv2.warpAffine(ref, shift, ref.shape[::-1], flags=cv2.INTER_NEAREST)
    contours, hier = cv2.findContours(ref, cv2.RETR_CCOMP, cv2.CHAIN_APPROX_NONE)
    top = [i for i in range(len(contours)) if hier[0][i][3] < 0]
    main = max(top, key=lambda i: cv2.contourArea(contours[i]))
    eps = 0.8
    outer = r.to_mm(cv2.approxPolyDP(contours[main], eps, True) + 0.5)
    min_hole = HOLE * float(np.median(areas))      # as the recipe's min_hole_mm2
    holes = []
    for i in range(len(contours)):
        if hier[0][i][3] == main and cv2.contourArea(contours[i]) * r.res ** 2 >= min_hole:
            holes.append(r.to_mm(cv2.approxPolyDP(contours[i], eps, True) + 0.5))
    sym, mirror = _symmetry(ref)
    grips, cup = _grips(ref, r, sym)
    pts = [(round(float(x), 2), round(float(y), 2)) for x, y in outer]
    hs = [[(round(float(x), 2), round(float(y), 2)) for x, y in h] for h in holes]
    return Outline(pts, hs, sym, mirror, grips, cup, len(ms))


def _holds(outline: Outline, grips: list[tuple[float, float]], cup_mm: float) -> bool:
    """Does every grip hold the whole cup on this pose's outline: inside it, at least the
    cup's radius from its edge, clear of its holes (as ``feeder check`` judges a pick)."""
    outer = np.asarray(outline.points_mm, np.float32).reshape(-1, 1, 2)
    holes = [np.asarray(h, np.float32).reshape(-1, 1, 2) for h in outline.holes_mm]
    for x, y in grips:
        pt = (float(x), float(y))
        if cv2.pointPolygonTest(outer, pt, True) < cup_mm:
            return False
        if any(cv2.pointPolygonTest(h, pt, True) > -cup_mm for h in holes):
            return False
    return True


def _grips(mask: np.ndarray, r: _Raster, sym: int) -> tuple[list[tuple[float, float]], float]:
    """Grip points on material clear of the edge and the holes: the centroid if it is
    nearly as clear as the clearest point, else the clearest point (turned about the
    centre by the part's symmetry, up to four grips)."""
    dist = cv2.distanceTransform(np.pad(mask, 1), cv2.DIST_L2, 5)[1:-1, 1:-1] * r.res
    c = int(round(r.half))
    best = float(dist.max())
    cup = max(0.5, round(0.5 * best, 1))
    if dist[c, c] >= 0.7 * best:
        return [(0.0, 0.0)], cup
    v, u = np.unravel_index(int(dist.argmax()), dist.shape)
    x, y = (u - r.half) * r.res, (v - r.half) * r.res
    n = 4 if sym == 360 else min(sym, 4)
    step = 360.0 / (n if sym == 360 else sym)
    out = []
    for k in range(n):
        a = math.radians(step * k)
        out.append((round(x * math.cos(a) - y * math.sin(a), 2),
                    round(x * math.sin(a) + y * math.cos(a), 2)))
    return out, cup


# ---------------------------------------------------------------------------- teach


def teach(samples: list[Sample], calibration: Calibration) -> Taught:
    """Learn a recipe, classes and outlines from the samples (see the module docstring)."""
    boxes = [b for s in samples for b in s.boxes
             if not b.touches_border(s.image.shape[1], s.image.shape[0])]
    if not boxes and not any(s.part for s in samples):
        raise BadInput("no labelled part clear of the images' edges to learn from")
    s2 = calibration.mm2_per_px2
    if boxes:
        size_px = float(np.median([math.sqrt(b.w * b.h) for b in boxes]))
        smallest = min(b.w * b.h for b in boxes) * math.pi / 4 * s2
    else:                              # --part folders only: the parts' size from Otsu
        probe = Locator(VisionRecipe(backlight=False, golden_image=False,
                                     threshold=Threshold("otsu", 5.0), min_area_mm2=0.0),
                        {}, calibration)
        areas = [d.features["area_mm2"] for s in samples for d in probe.measure_blobs(s.image)
                 if not d.reason]
        areas = [a for a in areas if a > 0.05 * max(areas, default=0)]
        if not areas:
            raise BadInput("no blobs in the --part images")
        smallest = float(np.median(areas))
        size_px = math.sqrt(smallest / s2)
    min_area = round_sig(SPECK * smallest, math.floor)
    # holes smaller than this share of the smallest part are specks of its surface
    min_hole = round_sig(HOLE * smallest, math.floor)
    seg, tried = choose_segmentation(samples, calibration, min_area, min_hole, size_px)
    measured = measure(seg, samples, calibration)
    missing = sorted({b.cls for b in boxes} - set(measured))
    if missing:
        raise BadInput(f"no sample of {', '.join('/'.join(c) for c in missing)} was found "
                       f"alone with the best segmentation ({seg.name}): label more images")
    ranges, separated = learn_classes(measured)
    recipe = VisionRecipe(
        backlight=False, golden_image=seg.recipe.golden_image,
        foreground=seg.recipe.foreground, threshold=seg.recipe.threshold,
        morphology=seg.recipe.morphology, min_area_mm2=min_area,
        min_hole_mm2=seg.recipe.min_hole_mm2, classes=[], orientation="none",
        check_clearance=True)
    outlines = {c: learn_outline(ms) for c, ms in measured.items()}
    return Taught(seg, recipe, ranges, measured, outlines, separated, tried)


def cell_calibration(cell: str) -> tuple[CellSpec, Calibration]:
    """The cell's camera calibration: the scale from pixels to mm."""
    spec = load_cell(cell)
    return spec, Calibration(spec.camera.calibration)


# ---------------------------------------------------------------------------- the YAML


def _pts(points: list[tuple[float, float]]) -> str:
    return "[" + ", ".join(f"[{fmt(x)}, {fmt(y)}]" for x, y in points) + "]"


def write_scenario(taught: Taught, out: str | Path, cell: str | Path, cell_spec: CellSpec,
                   n_images: int) -> list[str]:
    """Write the scenario (and the golden image it needs, if any); returns the files."""
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    cell_rel = Path(_relpath(Path(cell), out.parent))
    seg = taught.segmentation
    parts: dict[str, list[Cls]] = {}
    for c in sorted(taught.samples, key=lambda c: (c[0], -len(taught.samples[c]), c[1])):
        parts.setdefault(c[0], []).append(c)
    written = [str(out)]
    lines = [
        f"# Taught by `feeder teach` from {n_images} image(s): "
        f"{sum(len(v) for v in taught.samples.values())} sample part(s) in "
        f"{len(taught.samples)} class(es).",
        "# Every range, outline and pick point below was measured from the samples; edit",
        "# freely (the place positions and hopper counts are placeholders to fill in).",
        f"name: {out.stem}",
        f"cell: {cell_rel.as_posix()}",
        "tick_hz: 50",
        "",
        "parts:",
    ]
    safe = cell_spec.robot.safe_mm
    for k, (part, classes) in enumerate(parts.items()):
        main = taught.outlines[classes[0]]
        total = sum(len(taught.samples[c]) for c in classes)
        lines.append(f"  {part}:")
        lines.append(f"    # outline: the median silhouette of {main.samples} sample(s) of "
                     f"{part}/{classes[0][1]}, mm about its area centroid")
        lines += _shape_lines(main, "    shape:")
        lines.append("    poses:")
        probs = [round(len(taught.samples[c]) / total, 3) for c in classes]
        probs[0] = round(1.0 - sum(probs[1:]), 3)
        for c, p in zip(classes, probs, strict=True):
            n = len(taught.samples[c])
            if c == classes[0]:
                lines.append(f"      {c[1]}: {{probability: {fmt(p)}, pickable: true}}"
                             f"   # {n} sample(s)")
            elif _holds(taught.outlines[c], main.grips_mm, main.cup_radius_mm):
                lines.append(f"      {c[1]}:   # {n} sample(s); pickable: say false if the "
                             "gripper cannot take it")
                lines.append(f"        probability: {fmt(p)}")
                lines.append("        pickable: true")
            else:
                lines.append(f"      {c[1]}:   # {n} sample(s); the cup "
                             f"({fmt(main.cup_radius_mm)} mm) finds no hold at the grips on "
                             "this outline")
                lines.append(f"        probability: {fmt(p)}")
                lines.append("        pickable: false")
                lines += _shape_lines(taught.outlines[c], "        silhouette:")
        lines.append(f"    place: {{x: {fmt(round(safe[0] - 40 - 80 * k))}, "
                     f"y: {fmt(round(safe[1] + 30))}, z: 0}}   # FILL IN: where it goes")
        sym = main.symmetry
        what = ("the same however it is turned" if sym == 360 else
                f"the same turned by {fmt(round(360 / sym, 2))} deg" if sym > 1 else
                "no rotational symmetry")
        lines.append(f"    symmetry: {sym}   # measured: {what}")
        lines.append(f"    mirror_symmetric: {'true' if main.mirror_symmetric else 'false'}")
        lines.append("    # pick: on material, as clear of the edge and the holes as the "
                     "outline allows")
        lines.append("    pick:")
        lines.append("      grips: [" + ", ".join(
            f"{{offset_mm: [{fmt(x)}, {fmt(y)}]}}" for x, y in main.grips_mm) + "]")
        lines.append(f"      cup_radius_mm: {fmt(main.cup_radius_mm)}")
    lines += ["", "hopper:", "  parts: {" + ", ".join(f"{p}: 100" for p in parts) + "}", ""]
    r = taught.recipe
    th = r.threshold
    if th.method == "adaptive":
        th_yaml = f"{{method: adaptive, block_px: {th.block_px}, c: {fmt(th.c)}}}"
    else:
        th_yaml = f"{{method: {th.method}, value: {fmt(th.value)}}}"
    lines += [
        "vision:",
        "  backlight: false",
        f"  # segmentation: {seg.name}; it found {seg.good} of {seg.labels} labelled "
        f"part(s) alone",
        f"  # with {seg.stray} stray blob(s), the best of {taught.tried} tried",
        f"  golden_image: {'true' if r.golden_image else 'false'}",
    ]
    if r.golden_image and seg.golden is not None:
        golden = out.with_name(out.stem + "_golden.png")
        write_image(golden, seg.golden)
        written.append(str(golden))
        lines.append(f"  # the golden image is the median of the frames: {golden.name} "
                     "(feeder locate --golden)")
    lines += [
        f"  foreground: {r.foreground}",
        f"  threshold: {th_yaml}",
        f"  morphology: {{open_px: {r.morphology.open_px}, close_px: {r.morphology.close_px}}}",
        f"  min_area_mm2: {fmt(r.min_area_mm2)}   # a quarter of the smallest labelled part",
        f"  min_hole_mm2: {fmt(r.min_hole_mm2)}",
    ]
    if taught.split is not None:
        lines.append(f"  # touching parts cut apart or not: F1 {taught.split[1]:.3f} or "
                     f"{taught.split[0]:.3f} on the teaching images")
    if taught.split is not None or r.split_touching:
        lines.append(f"  split_touching: {'true' if r.split_touching else 'false'}")
    for a, b, feat in taught.separated:
        lines.append(f"  # {'/'.join(a)} and {'/'.join(b)} are told apart by {feat}")
    lines.append("  classes:")
    for classes in parts.values():
        for c in classes:
            rg = taught.ranges[c]
            items = [f"part: {c[0]}", f"pose: {c[1]}", "pickable: true"]
            items += [f"{n}: [{fmt(lo)}, {fmt(hi)}]" for n, (lo, hi) in rg.items()]
            lines.append(f"    # {len(taught.samples[c])} sample(s): their spread and a "
                         "margin, or halfway to the next class (the area's top: to two "
                         "touching)")
            lines.append("    - {" + ", ".join(items) + "}")
    # a frame every so far along the belt: each part whole in at least one frame
    cam = cell_spec.camera
    window = cam.height_px * cam.calibration.mm_per_px
    largest = max(2 * max(math.hypot(x, y) for x, y in o.points_mm)
                  for o in taught.outlines.values())
    spacing = round_sig(max(0.8 * (window - largest), 0.1 * window), math.floor)
    lines += [
        "  orientation: none",
        "",
        "present:",
        "  mode: continuous",
        "  horizontal_mm_s: 150",
        "  incline_pct: 40",
        "",
        "locate:",
        f"  frame_spacing_mm: {fmt(spacing)}   # the camera window less the largest part",
        "",
        "retrieve:",
        "  policy: earliest_deadline",
        "",
        "adjust:",
        "  algorithm: none",
        "",
    ]
    out.write_text("\n".join(lines))
    return written


def _shape_lines(o: Outline, head: str) -> list[str]:
    ind = " " * (len(head) - len(head.lstrip()) + 2)
    lines = [head, f"{ind}polygon:", f"{ind}  points_mm: {_pts(o.points_mm)}"]
    if o.holes_mm:
        lines.append(f"{ind}  holes_mm: [" + ", ".join(_pts(h) for h in o.holes_mm) + "]")
    return lines


def _relpath(target: Path, start: Path) -> str:
    import os
    return os.path.relpath(target.resolve(), start.resolve())
