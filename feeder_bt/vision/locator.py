"""The OpenCV locator: a grey image -> poses of singulated parts in the belt frame.

It sees only pixels, the cell's calibration and the recipe — never ground truth.
Pipeline: the image in which parts are bright (``foreground: dark``: the golden image minus
the frame, or the inverted frame; ``light``: the frame minus the golden image, or the
frame), threshold, morphology, external contours (with their holes, ``RETR_CCOMP``, when a
class ranges over ``holes`` or ``hole_area_mm2``); blobs touching the image border or
smaller than ``min_area_mm2`` are rejected; features (``FEATURES``) are measured in mm (mm² for areas) through the
calibration, corrected for pixelisation so that they are close to the physical value (a
50.8 mm disc: ~2030 mm², circularity ~0.99); the first recipe class whose ranges all hold
names the part and pose. Position is the blob's area centroid, which is the part frame's
origin (``geometry``).
Merged (touching) parts fall outside every class and are rejected, so they are never
picked; a blob that fits no class is rejected with the class nearest it by area and the
first of that class's ranges it is outside (``Locator._no_class``).

Features are measured as a cascade, cheapest first (``features.GROUPS``): every blob gets
its area and centroid from the contour's moments; a class's other features are measured
only when the blob is checked against that class and its cheaper ranges held. So a
``Detection``'s ``features`` hold ``area_mm2`` plus the features its checks needed (and
``mirrored`` once a face was looked at) — a flat lens has area, perimeter and circularity,
a blob rejected as too big only its area. ``locate(..., all_features=True)`` and
``measure_blobs`` measure every feature of every blob, for tools that show or tune them.

Recipe semantics worth knowing:

* ``threshold.method``: ``fixed`` (``value`` grey levels of difference), ``otsu`` (Otsu's
  level, but never below ``value``, so an empty belt does not turn noise into blobs), or
  ``adaptive`` (``block_px``; foreground above the local mean minus ``c``: OpenCV's
  ``C``, so ``c`` < 0).
* ``orientation``: ``none`` -> 0; ``principal_axis`` -> the long axis from moments, in
  (-90, 90]; ``cut_corner`` -> for classes with ``mirrored`` set, the angle (and face) at
  which the part's ``face_up`` outline matches the blob, in (-180, 180]; other classes
  fall back to the principal axis when elongated, else 0. The face and angle are read
  from the blob's outline to a fraction of a pixel (``Locator._faces``).

Each call of ``locate`` uses only local state and per-thread scratch images (the golden
image is read, never written), so one ``Locator`` may serve several threads.
"""

from __future__ import annotations

import bisect
import math
import threading
import time
from dataclasses import dataclass, field

import cv2
import numpy as np

from ..geometry import pose_outline, wrap_deg
from ..scenario.model import PartSpec, VisionClass, VisionRecipe
from .calibration import Calibration
from .chains import WINDOW as _WINDOW  # noqa: F401  (tests read it here)
from .chains import _chain_steps, _first, _full_chain, _runs, _smooth_length, _with_holes
from .corners import (
    _angle,
    _corner_signature,
    _corner_signatures,  # noqa: F401  (tests read it here)
    _CornerSignature,
    _cross,
    _densify,
)
from .features import FEATURES, GROUP_OF

_ELONGATED = 1.3               # aspect above which a symmetric blob has a principal axis
# the four 4-neighbours of a pixel (u, v): where the outline may cross between them
_DU = np.array([1, -1, 0, 0])
_DV = np.array([0, 0, 1, -1])


@dataclass
class Detection:
    """One blob: its class (None if rejected, with ``reason``), pose in the belt frame and
    in pixels, and the features measured on the way (see the module docstring)."""

    part: str | None
    pose: str | None
    pickable: bool
    x_mm: float
    y_mm: float
    angle_deg: float
    u_px: float
    v_px: float
    features: dict[str, float]
    reason: str = ""           # empty if accepted, else why rejected


@dataclass
class LocateResult:
    parts: list[Detection]
    rejected: list[Detection]
    ms: float
    contours: list[np.ndarray] = field(default_factory=list, repr=False)  # parts + rejected, px


class _Blob:
    """One contour on its way through the cascade: what has been measured so far."""

    __slots__ = ("contour", "box", "mom", "area_px", "det", "full", "length", "hull", "faced",
                 "face", "oriented", "holes")

    def __init__(self, contour: np.ndarray, box: tuple[int, int, int, int],
                 mom: dict[str, float], area_px: float, det: Detection, full: bool,
                 holes: list[np.ndarray] | None = None) -> None:
        self.contour = contour            # (n, 1, 2) int32, whole-frame pixels
        self.holes = holes                # its hole contours (None: not looked for)
        self.full = full                  # every boundary pixel (else the chain's corners)
        self.box = box                    # bounding box u, v, width, height
        self.mom = mom                    # its moments (cv2.moments)
        self.area_px = area_px            # pixel count (Pick's theorem on the contour)
        self.det = det
        self.length: float | None = None  # smoothed contour length, px (``_smooth_length``)
        self.hull: np.ndarray | None = None         # convex hull (``Locator._hull``)
        self.faced = False                # ``face`` measured (``Locator._faces``)
        self.face: _CornerSignature | None = None   # the cut-corner signature of its outline
        self.oriented: dict[str, tuple[float, bool] | None] = {}   # part -> angle, face


# ---------------------------------------------------------------------------- locator


class Locator:
    """Finds parts in images with one recipe; see the module docstring."""

    def __init__(self, recipe: VisionRecipe, parts: dict[str, PartSpec],
                 calibration: Calibration) -> None:
        self.recipe = recipe
        self.parts = parts
        self.calibration = calibration
        self._golden: np.ndarray | None = None
        self._light = recipe.foreground == "light"   # parts brighter than the belt
        for cls in recipe.classes:
            for name in cls.ranges:
                if name not in FEATURES:
                    raise ValueError(f"class {cls.part}/{cls.pose}: unknown feature {name!r}")
        # each class's ranges, cheapest feature first: the cascade's order of checks
        self._checks: list[tuple[VisionClass, list[tuple[str, float, float]]]] = [
            (cls, sorted(((n, lo, hi) for n, (lo, hi) in cls.ranges.items()),
                         key=lambda r: GROUP_OF[r[0]]))
            for cls in recipe.classes]
        # The smoothed perimeter and the face's outline read every boundary pixel of the
        # contour; without them only the chain's corners are kept (the same polygon: the
        # same moments, hull and rectangle, fewer points to trace and sum).
        self._full_chain = any(GROUP_OF[n] == GROUP_OF["perimeter_mm"]
                               for cls in recipe.classes for n in cls.ranges) or (
            recipe.orientation == "cut_corner"
            and any(cls.mirrored is not None for cls in recipe.classes))
        # hole contours are searched for only when a class ranges over them
        self._want_holes = any(GROUP_OF[n] == GROUP_OF["holes"]
                               for cls in recipe.classes for n in cls.ranges)
        self._signatures: dict[str, _CornerSignature] = {}
        if recipe.orientation == "cut_corner":
            for cls in recipe.classes:
                if cls.mirrored is None or cls.part in self._signatures:
                    continue
                model = _densify(pose_outline(parts[cls.part], _face_up(parts[cls.part])))
                sig = _corner_signature(model)
                if sig is None:
                    raise ValueError(f"part {cls.part}: no cut corner to orient by")
                self._signatures[cls.part] = sig
        m = recipe.morphology
        self._open = (cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (m.open_px, m.open_px))
                      if m.open_px > 1 else None)
        self._close = (cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (m.close_px, m.close_px))
                       if m.close_px > 1 else None)
        # Opening then closing reads the thresholded mask up to this far (px) from a pixel:
        # regions of the image this far clear of foreground are left empty by them.
        reach = sum(2 * (k.shape[0] // 2) for k in (self._open, self._close) if k is not None)
        self._margin = reach + 1
        # kernels symmetric about their centre: an image's mirror stays its mirror
        self._mirror = all(k.shape[0] % 2 == 1 and k.shape[1] % 2 == 1
                           and (k == k[::-1]).all() and (k == k[:, ::-1]).all()
                           for k in (self._open, self._close) if k is not None)
        self._below: np.ndarray | None = None     # golden - level: fixed threshold in one pass
        self._scratch = threading.local()         # per-thread frame-sized images, reused

    # -------------------------------------------------------------- images

    def set_golden(self, image: np.ndarray) -> None:
        """Remember the cleared belt; later frames are compared against it."""
        self._golden = _grey(image).copy()
        th = self.recipe.threshold
        self._below = None
        if th.method == "fixed" and 0 <= math.floor(th.value) < 255:
            if self._light:
                # frame - golden > t  <=>  frame > golden + t (saturated at 255: never above)
                self._below = cv2.add(self._golden, math.floor(th.value))
            else:
                # golden - frame > t  <=>  frame < golden - t (saturated at 0: never below)
                self._below = cv2.subtract(self._golden, math.floor(th.value))

    def foreground(self, image: np.ndarray) -> np.ndarray:
        """Binary mask (0/255) of what the recipe considers parts."""
        return self._morph(self._threshold(_grey(image))[0].copy())

    def _buffer(self, name: str, shape: tuple[int, ...]) -> np.ndarray:
        """A frame-sized uint8 scratch image of this thread's, reused from frame to frame.

        A fresh frame-sized array each frame costs more than the operation writing it when
        the allocator hands the pages back and faults them in again (2-3x on the bench).
        """
        bufs: dict[str, np.ndarray] | None = getattr(self._scratch, "bufs", None)
        if bufs is None:
            bufs = self._scratch.bufs = {}
        buf = bufs.get(name)
        if buf is None or buf.shape != shape:
            buf = bufs[name] = np.empty(shape, dtype=np.uint8)
        return buf

    def _diff(self, img: np.ndarray, dst: np.ndarray | None = None) -> np.ndarray:
        """The image in which parts are bright: for dark parts the golden image minus the
        frame (or the inverted frame), for light parts the frame minus the golden image
        (or the frame itself)."""
        golden = self._golden
        if self.recipe.golden_image and golden is not None:
            if self._light:
                return cv2.subtract(img, golden, dst=dst)
            return cv2.subtract(golden, img, dst=dst)
        if self._light:
            return img
        return cv2.bitwise_not(img, dst=dst)

    def _threshold(self, img: np.ndarray) -> tuple[np.ndarray, np.ndarray | None, float | None]:
        """The thresholded mask (before morphology), the difference image (None if it was
        not needed) and the level (None: adaptive). The images are this thread's scratch
        images, valid until its next frame."""
        th = self.recipe.threshold
        mask = self._buffer("mask", img.shape)
        if th.method == "fixed" and self.recipe.golden_image and self._below is not None \
                and self._below.shape == img.shape:
            # the same mask as subtract-then-threshold, in one pass over the frame
            return (cv2.compare(img, self._below, cv2.CMP_GT if self._light else cv2.CMP_LT,
                                dst=mask), None, float(th.value))
        diff = self._diff(img, self._buffer("diff", img.shape))
        if th.method == "fixed":
            level: float | None = float(th.value)
            cv2.threshold(diff, th.value, 255, cv2.THRESH_BINARY, dst=mask)
        elif th.method == "otsu":
            level, _ = cv2.threshold(diff, 0, 255, cv2.THRESH_BINARY | cv2.THRESH_OTSU,
                                     dst=mask)
            if level < th.value:
                level = float(th.value)
                cv2.threshold(diff, th.value, 255, cv2.THRESH_BINARY, dst=mask)
        elif th.method == "adaptive":
            level = None
            block = max(3, int(th.block_px) | 1)
            # OpenCV's meaning of C: foreground where the part-bright image is above its
            # local mean minus c (so c < 0: that far above the mean)
            cv2.adaptiveThreshold(diff, 255, cv2.ADAPTIVE_THRESH_MEAN_C,
                                  cv2.THRESH_BINARY, block, th.c, dst=mask)
        else:
            raise ValueError(f"unknown threshold method {th.method!r}")
        return mask, diff, level

    def _morph(self, mask: np.ndarray) -> np.ndarray:
        if self._open is not None:
            mask = cv2.morphologyEx(mask, cv2.MORPH_OPEN, self._open)
        if self._close is not None:
            mask = cv2.morphologyEx(mask, cv2.MORPH_CLOSE, self._close)
        return mask

    def _rois(self, mask: np.ndarray) -> list[tuple[int, int, int, int]]:
        """Rectangles (v0, v1, u0, u1) that hold all the foreground, each with a margin of
        empty pixels wider than the morphology reaches (or the image's edge).

        Rows with foreground are cut into bands where ``2 * margin`` empty rows part them,
        then each band's columns likewise: most of a frame is empty belt.
        """
        h, w = mask.shape
        m = self._margin
        rows = cv2.reduce(mask, 1, cv2.REDUCE_SUM, dtype=cv2.CV_32S).ravel().nonzero()[0]
        if len(rows) == 0:
            return []
        out = []
        for a, b in _runs(rows, 2 * m):
            cols = cv2.reduce(mask[a:b + 1], 0, cv2.REDUCE_SUM,
                              dtype=cv2.CV_32S).ravel().nonzero()[0]
            v0, v1 = max(a - m, 0), min(b + m + 1, h)
            out += [(v0, v1, max(c0 - m, 0), min(c1 + m + 1, w))
                    for c0, c1 in _runs(cols, 2 * m)]
        return out

    def _contours(self, mask: np.ndarray, full: bool) -> list[np.ndarray]:
        """External contours of the opened and closed ``mask`` (``_contours_holes``)."""
        return self._contours_holes(mask, full, holes=False)[0]

    def _contours_holes(self, mask: np.ndarray, full: bool, holes: bool
                        ) -> tuple[list[np.ndarray], list[list[np.ndarray]] | None]:
        """External contours of the opened and closed ``mask``, in ``findContours``' order
        (as on the whole frame: by first point, last found first), and with ``holes`` each
        one's hole contours (``RETR_CCOMP``; else None).

        The morphology and the contour search run only on ``_rois``: inside each, every
        pixel comes out as on the whole frame, outside them nothing does. The rectangles
        are laid side by side in one small image (their margins keep them apart, as on the
        frame), so a frame costs two morphology calls and one contour search however many
        blobs it has. Where a rectangle meets the image's edge, which the morphology reads
        as "nothing there to constrain", it gets a mirror image of itself as wide as the
        margin: with a symmetric kernel each operation keeps the mirror a mirror, so up to
        the edge every pixel comes out as on the frame. The mirrors are cleared before the
        contour search (whose own border is empty, as at the image's edge).
        """
        h, w = mask.shape
        rois = self._rois(mask)
        if not rois:
            return [], ([] if holes else None)
        mode = cv2.RETR_CCOMP if holes else cv2.RETR_EXTERNAL
        chain = cv2.CHAIN_APPROX_NONE if full else cv2.CHAIN_APPROX_SIMPLE
        morph = self._open is not None or self._close is not None
        # a rectangle at the image's edge has no empty margin there: it gets a mirror (for
        # the morphology), which also keeps it one pixel clear of its neighbours
        pad = self._margin if morph else 1
        out: list[tuple[int, np.ndarray, list[np.ndarray]]] = []   # (whole frame's raster
        # index of the 1st point, contour, its holes)
        srcs: list[tuple[int, np.ndarray]] = []   # (x in the packed image, pixels)
        starts: list[int] = []
        shifts: list[int] = []                    # packed -> frame, u + (v << 32): an int64 add
        mirrors = []
        x = height = 0
        for v0, v1, u0, u1 in rois:
            src = mask[v0:v1, u0:u1]
            top = left = 0
            if v0 == 0 or u0 == 0 or v1 == h or u1 == w:
                top, bottom, left, right = pad * (v0 == 0), pad * (v1 == h), \
                    pad * (u0 == 0), pad * (u1 == w)
                if morph and not self._mirror:
                    cs, hier = cv2.findContours(self._morph(src), mode, chain, offset=(u0, v0))
                    out += [(c.item(1) * w + c.item(0), c, hs)
                            for c, hs in _with_holes(cs, hier, holes)]
                    continue
                src = cv2.copyMakeBorder(src, top, bottom, left, right, cv2.BORDER_REFLECT_101)
                mirrors.append((x, top, bottom, left, right, src.shape))
            srcs.append((x, src))
            starts.append(x)
            shifts.append(u0 - x - left + ((v0 - top) << 32))
            x += src.shape[1]
            height = max(height, src.shape[0])
        if srcs:
            packed = np.zeros((height, x), dtype=np.uint8)
            for x0, src in srcs:
                packed[:src.shape[0], x0:x0 + src.shape[1]] = src
            if morph:
                packed = self._morph(packed)
            for x0, top, bottom, left, right, (sh, sw) in mirrors:
                if top:
                    packed[:top, x0:x0 + sw] = 0
                if bottom:
                    packed[sh - bottom:sh, x0:x0 + sw] = 0
                if left:
                    packed[:, x0:x0 + left] = 0
                if right:
                    packed[:, x0 + sw - right:x0 + sw] = 0
            cs, hier = cv2.findContours(packed, mode, chain)
            for c, hs in _with_holes(cs, hier, holes):
                shift = shifts[bisect.bisect_right(starts, c.item(0)) - 1]
                for k in (c, *hs):               # a blob's holes lie in its rectangle
                    flat = k.view(np.int64)
                    flat += shift
                out.append((c.item(1) * w + c.item(0), c, hs))
        # the whole frame's findContours lists contours by first point, last found first
        out.sort(key=_first, reverse=True)
        return [c for _, c, _ in out], ([hs for _, _, hs in out] if holes else None)

    # -------------------------------------------------------------- locate

    def locate(self, image: np.ndarray, all_features: bool = False) -> LocateResult:
        """Find, measure and classify every blob in ``image``.

        ``all_features``: measure every feature of every blob (for tools that show them),
        not only those the cascade needed (see the module docstring).
        """
        t0 = time.perf_counter()
        img = _grey(image)
        mask, diff, level = self._threshold(img)
        full = all_features or self._full_chain
        contours, holes = self._contours_holes(mask, full, all_features or self._want_holes)
        blobs = self._blobs(contours, img.shape[:2], all_features, full=full, holes=holes)
        # classes first; the blobs that need a face wait for one batch of fine outlines
        waiting = [b for b in blobs if not b.det.reason and not self._classify(b)]
        if waiting:
            self._faces(waiting, img, diff, level)
            for b in waiting:
                self._classify(b)
        parts: list[Detection] = []
        rejected: list[Detection] = []
        for b in blobs:
            (rejected if b.det.reason else parts).append(b.det)
        ms = (time.perf_counter() - t0) * 1e3
        return LocateResult(parts=parts, rejected=rejected, ms=ms,
                            contours=[b.contour for b in blobs])

    def measure_blobs(self, image: np.ndarray) -> list[Detection]:
        """Every blob's features, unclassified, measured exactly as ``locate`` measures them
        (all of ``FEATURES``, as with ``all_features``).

        For tools that tune a recipe (``feeder recipe suggest``): one feature extractor for
        tuning and feeding. ``reason`` marks blobs ``locate`` would reject before
        classification ("touches border", "too small"); ``part`` is always None.
        """
        img = _grey(image)
        contours, holes = self._contours_holes(self._threshold(img)[0], True, True)
        blobs = self._blobs(contours, img.shape[:2], all_features=True, full=True, holes=holes)
        return [b.det for b in blobs]

    # -------------------------------------------------------------- per blob

    def _blobs(self, contours: list[np.ndarray], shape: tuple[int, int], all_features: bool,
               full: bool = True, holes: list[list[np.ndarray]] | None = None) -> list[_Blob]:
        """The contours worth reporting (not specks), measured as far as every blob is:
        area, centroid (mm), the border and size rules; with ``all_features`` every feature
        of every blob, the rejected ones too.

        ``full``: the contours have every boundary pixel (else only the chain's corners).
        ``holes``: each contour's hole contours, if they were looked for.
        The centroids go to mm in one call.
        """
        h, w = shape
        s2 = self.calibration.mm2_per_px2
        min_px = self.recipe.min_area_mm2 / s2
        blobs: list[_Blob] = []
        centres = []
        for i, c in enumerate(contours):
            box = cv2.boundingRect(c)
            if box[2] * box[3] < min_px * 0.5:
                continue
            bu, bv, bw, bh = box
            mom = cv2.moments(c)
            m00 = mom["m00"]
            # The contour runs through the centres of the boundary pixels; by Pick's theorem
            # the blob's pixel count is the polygon's area + boundary pixels / 2 + 1.
            area_px = abs(m00) + 1.0                # + boundary pixels / 2, below
            if m00 != 0:
                cu, cv = mom["m10"] / m00, mom["m01"] / m00
            else:
                cu, cv = (float(v) for v in c.reshape(-1, 2).mean(axis=0))
            centres.append((cu, cv))
            touches = bu <= 0 or bv <= 0 or bu + bw >= w or bv + bh >= h
            det = Detection(None, None, False, 0.0, 0.0, 0.0, cu, cv, {},
                            "touches border" if touches else "")
            blobs.append(_Blob(c, box, mom, area_px, det, full,
                               None if holes is None else holes[i]))
        if not blobs:
            return blobs
        steps = ([len(b.contour) for b in blobs] if full
                 else _chain_steps([b.contour for b in blobs]))
        for b, n in zip(blobs, steps, strict=True):
            b.area_px += 0.5 * n
            b.det.features["area_mm2"] = area = b.area_px * s2
            if not b.det.reason and area < self.recipe.min_area_mm2:
                b.det.reason = "too small"
        xy = self.calibration.px_to_mm(np.array(centres)).tolist()
        for b, (x, y) in zip(blobs, xy, strict=True):
            b.det.x_mm, b.det.y_mm = x, y
        if all_features:
            for b in blobs:
                for name in FEATURES:
                    self._feature(b, name)
        if self.recipe.orientation == "principal_axis":
            for b in blobs:            # as before the cascade: the rejected ones' too
                b.det.angle_deg = self._principal_angle(cv2.moments(self._contour_mm(b)))
        return blobs

    def _feature(self, b: _Blob, name: str) -> float:
        """One feature of the blob, measuring its group (``features.GROUPS``) if not yet.

        The calibration is a similarity (scale, rotation, reflection), so lengths scale by
        ``mm_per_px``, areas by its square and the ratios and Hu invariants not at all:
        shape features are measured on the pixel contour (cheaper) and scaled.
        """
        feats = b.det.features
        v = feats.get(name)
        if v is not None:
            return v
        s = self.calibration.mm_per_px
        c, area_px = b.contour, b.area_px
        group = GROUP_OF[name]
        if group == GROUP_OF["holes"]:
            # A hole contour runs through the blob's pixels around the hole: by Pick's
            # theorem the hole's pixel count is the polygon's area - boundary pixels / 2 + 1.
            if b.holes is None:
                raise RuntimeError("hole features asked of a blob whose holes were not found")
            s2 = self.calibration.mm2_per_px2
            steps = (([len(k) for k in b.holes] if b.full else _chain_steps(b.holes))
                     if b.holes else [])
            areas = [(abs(cv2.contourArea(k)) - 0.5 * n + 1.0) * s2
                     for k, n in zip(b.holes, steps, strict=True)]
            big = [a for a in areas if a >= self.recipe.min_hole_mm2]
            feats["holes"] = float(len(big))
            feats["hole_area_mm2"] = float(sum(big))
        elif group == GROUP_OF["hu1"]:
            # the first two Hu invariants, as cv2.HuMoments computes them (same operations)
            mom = b.mom
            if mom["m00"] != 0:
                n20, n02, n11 = mom["nu20"], mom["nu02"], mom["nu11"]
                feats["hu1"] = float(n20 + n02)
                feats["hu2"] = float((n20 - n02) * (n20 - n02) + 4 * n11 * n11)
            else:
                feats["hu1"] = feats["hu2"] = 0.0
        elif group == GROUP_OF["perimeter_mm"]:
            if b.length is None:
                b.length = _smooth_length(c if b.full else _full_chain(c))
            # A pixel staircase is up to 8 % longer than the edge it follows: measure the
            # contour smoothed along itself instead, then move it out the half pixel to the
            # blob's edge (which adds 2·π·0.5 to a closed convex outline).
            perim = b.length + math.pi
            feats["perimeter_mm"] = perim * s
            feats["circularity"] = (4 * math.pi * area_px / (perim * perim)
                                    if perim > 0 else 0.0)
        elif group == GROUP_OF["aspect"]:
            # the rectangle of the hull is the contour's (the hull is kept for the face)
            (_, _), (rw, rh), _ = cv2.minAreaRect(self._hull(b))
            rw, rh = rw + 1.0, rh + 1.0
            feats["aspect"] = max(rw, rh) / min(rw, rh) if min(rw, rh) > 0 else 0.0
            feats["rectangularity"] = area_px / (rw * rh) if rw * rh > 0 else 0.0
        elif group == GROUP_OF["solidity"]:
            hull = self._hull(b)
            hull_area = cv2.contourArea(hull) + 0.5 * cv2.arcLength(hull, True) + 1.0
            feats["solidity"] = min(area_px / hull_area, 1.0) if hull_area > 0 else 0.0
        return feats[name]

    def _in_ranges(self, b: _Blob, checks: list[tuple[str, float, float]]) -> bool:
        """Whether every range of a class holds, measuring features only as far as needed."""
        feats = b.det.features
        for name, lo, hi in checks:
            v = feats.get(name)
            if v is None:
                v = self._feature(b, name)
            if not lo <= v <= hi:
                return False
        return True

    @staticmethod
    def _hull(b: _Blob) -> np.ndarray:
        """The contour's convex hull, (k, 1, 2) pixels (measured once per blob)."""
        if b.hull is None:
            b.hull = cv2.convexHull(b.contour)
        return b.hull

    def _contour_mm(self, b: _Blob) -> np.ndarray:
        """The pixel contour mapped to belt mm (float32), for angles."""
        return self.calibration.px_to_mm(b.contour.reshape(-1, 2)).astype(np.float32)

    def _faces(self, blobs: list[_Blob], img: np.ndarray, diff: np.ndarray | None,
               level: float | None) -> None:
        """Measure each blob's cut-corner signature (``_Blob.face``) on its outline to a
        fraction of a pixel, all of a frame's blobs in one set of array operations.

        A binary contour moves in whole pixels, which limits the angle of a near-axis edge
        to about 1°. The grey levels say where the edge is: between each boundary pixel of
        the contour (a recipe with faces keeps them all) and each of its 4-neighbours
        outside the level, the difference image (interpolated linearly, as a bilinear image
        is along that line) crosses the level at one point. Only the blob's own boundary is
        read, so a neighbour in its box is no trouble. Without a level (adaptive threshold),
        or if a blob has too few such points, the contours' pixels are used.
        """
        contours = [b.contour for b in blobs]
        uv = np.concatenate(contours).reshape(-1, 2)
        counts = [len(c) for c in contours]
        pts: np.ndarray = uv
        if level is not None:
            w = img.shape[1]
            at = uv[:, 1] * w + uv[:, 0]          # inside the image: touching blobs are out
            near = at[:, None] + np.array([1, -1, w, -w])        # the 4-neighbours, a row each
            inside, around = self._diff_at(img, diff, at), self._diff_at(img, diff, near)
            cut = math.floor(level)              # THRESH_BINARY: value > floor(level) is in
            i, k = ((around <= cut) & (inside > cut)[:, None]).nonzero()    # i ascending
            found = np.bincount(np.repeat(np.arange(len(blobs)), counts)[i],
                                minlength=len(blobs))
            if found.min() >= 3:
                a = inside[i].astype(np.float64)
                t = (a - (cut + 0.5)) / (a - around[i, k])  # the level between grey steps
                pts = np.empty((len(i), 2))
                pts[:, 0] = uv[i, 0] + t * _DU[k]
                pts[:, 1] = uv[i, 1] + t * _DV[k]
                counts = found.tolist()
        xy = self.calibration.px_to_mm(pts).astype(np.float32)
        ends = np.cumsum(counts).tolist()
        sigs = _corner_signatures([xy[e - n:e] for e, n in zip(ends, counts, strict=True)])
        for b, sig in zip(blobs, sigs, strict=True):
            b.face, b.faced = sig, True

    def _diff_at(self, img: np.ndarray, diff: np.ndarray | None, at: np.ndarray) -> np.ndarray:
        """``_diff`` at flat pixel indices ``at`` (from the frame's if it was made)."""
        if diff is not None:
            return diff.ravel()[at]
        golden = self._golden
        if self.recipe.golden_image and golden is not None:
            g = golden.ravel()[at].astype(np.int16)
            d = img.ravel()[at] - g if self._light else g - img.ravel()[at]
            return np.maximum(d, 0).astype(np.uint8)
        return img.ravel()[at] if self._light else 255 - img.ravel()[at]

    @staticmethod
    def _principal_angle(mom: dict[str, float]) -> float:
        a = 0.5 * math.atan2(2 * mom["mu11"], mom["mu20"] - mom["mu02"])
        return wrap_deg(math.degrees(a), 180.0)

    def _classify(self, b: _Blob) -> bool:
        """First class whose ranges (and face, for chiral parts) fit; else a reason. False
        (nothing decided) if a chiral class fits but the blob's face is not measured yet:
        ``_faces`` measures it, then this runs again.

        Classes are tried in the recipe's order, each range cheapest first, so a feature
        is measured only when a class still fits without it.
        """
        det = b.det
        chosen: VisionClass | None = None
        looked = False                       # a face was asked for
        for cls, checks in self._checks:
            if not self._in_ranges(b, checks):
                continue
            if cls.mirrored is None:
                chosen = cls
                det.angle_deg = self._symmetric_angle(b)
                break
            model = self._signatures.get(cls.part) if self.recipe.orientation == "cut_corner" \
                else None
            if model is None:
                chosen = cls                  # no way to tell the faces apart: trust the class
                break
            if not b.faced:
                return False
            looked = True
            oriented = b.oriented.get(cls.part, False)
            if oriented is False:
                oriented = b.oriented[cls.part] = self._orient(model, b.face)
            if oriented is None:
                continue
            angle, mirrored = oriented
            det.features["mirrored"] = 1.0 if mirrored else 0.0
            if mirrored == cls.mirrored:
                chosen = cls
                det.angle_deg = angle
                break
        if chosen is None:
            det.reason = "no class (face)" if looked else self._no_class(b)
        else:
            det.part, det.pose, det.pickable = chosen.part, chosen.pose, chosen.pickable
        return True

    def _no_class(self, b: _Blob) -> str:
        """Why a blob fits no class: the class nearest it by area and the first of that
        class's ranges it is outside (already measured: the cascade stopped there)."""
        if not self._checks:
            return "no class (the recipe has none)"
        area = b.det.features["area_mm2"]

        def far(item: tuple[VisionClass, list[tuple[str, float, float]]]) -> float:
            lo, hi = item[0].ranges.get("area_mm2", (area, area))
            return max(lo - area, area - hi, 0.0) / max(hi, 1e-9)

        cls, checks = min(self._checks, key=far)
        for name, lo, hi in checks:
            v = self._feature(b, name)
            if not lo <= v <= hi:
                return (f"no class; nearest {cls.part}/{cls.pose}: {name} {v:.4g} not in "
                        f"[{lo:.4g}, {hi:.4g}]")
        return f"no class; nearest {cls.part}/{cls.pose}: its face"

    def _symmetric_angle(self, b: _Blob) -> float:
        """Angle of a class without a face to tell: its long axis if it has one, else 0."""
        o = self.recipe.orientation
        if o == "none":
            return 0.0
        if o == "principal_axis":
            return b.det.angle_deg            # measured with the blob
        if self._feature(b, "aspect") > _ELONGATED:
            return self._principal_angle(cv2.moments(self._contour_mm(b)))
        return 0.0

    @staticmethod
    def _cut_corner(model: _CornerSignature, xy: np.ndarray) -> tuple[float, bool] | None:
        """Angle (deg) and face at which the model outline matches the blob, or None."""
        return Locator._orient(model, _corner_signature(np.asarray(xy, dtype=float)
                                                        .reshape(-1, 2)))

    @staticmethod
    def _orient(model: _CornerSignature, obs: _CornerSignature | None
                ) -> tuple[float, bool] | None:
        """Angle (deg) and face at which the model's signature matches the blob's."""
        if obs is None:
            return None
        mirrored = (_cross(model.corner, model.leg) * _cross(obs.corner, obs.leg)) < 0
        mc = (model.corner[0], -model.corner[1]) if mirrored else model.corner
        coarse = _angle(obs.corner) - _angle(mc)
        # fine angle: the observed rectangle's angle, moved by the model's own, mod 90°
        fine = obs.alpha - (-model.alpha if mirrored else model.alpha)
        k = round((coarse - fine) / (math.pi / 2))
        return wrap_deg(math.degrees(fine + k * math.pi / 2)), mirrored

    # -------------------------------------------------------------- drawing

    def annotate(self, image: np.ndarray, result: LocateResult) -> np.ndarray:
        """A BGR copy of ``image`` with parts (green), rejects (red) and their reasons."""
        img = _grey(image)
        out = cv2.cvtColor(img, cv2.COLOR_GRAY2BGR)
        if result.contours:
            cv2.drawContours(out, result.contours, -1, (255, 160, 0), 1, cv2.LINE_AA)
        cal = self.calibration
        for det in result.parts:
            c = (int(round(det.u_px)), int(round(det.v_px)))
            cv2.circle(out, c, 3, (0, 200, 0), -1, cv2.LINE_AA)
            a = math.radians(det.angle_deg)
            tip = cal.mm_to_px(np.array([[det.x_mm + 25 * math.cos(a),
                                          det.y_mm + 25 * math.sin(a)]]))[0]
            cv2.arrowedLine(out, c, (int(round(tip[0])), int(round(tip[1]))), (0, 200, 0), 1,
                            cv2.LINE_AA, tipLength=0.25)
            label = f"{det.part}/{det.pose}" + ("" if det.pickable else " (no pick)")
            _label(out, label, c, -6, (0, 160, 0))
        for det in result.rejected:
            c = (int(round(det.u_px)), int(round(det.v_px)))
            cv2.drawMarker(out, c, (0, 0, 230), cv2.MARKER_TILTED_CROSS, 10, 2)
            _label(out, det.reason, c, 14, (0, 0, 230))
        return out


def _label(out: np.ndarray, text: str, at: tuple[int, int], dy: int,
           colour: tuple[int, int, int]) -> None:
    """Text beside a point, kept inside the image."""
    (tw, th), _ = cv2.getTextSize(text, cv2.FONT_HERSHEY_SIMPLEX, 0.4, 1)
    x = min(at[0] + 6, out.shape[1] - tw - 2)
    y = min(max(at[1] + dy, th + 2), out.shape[0] - 4)
    cv2.putText(out, text, (max(x, 0), y), cv2.FONT_HERSHEY_SIMPLEX, 0.4, colour, 1,
                cv2.LINE_AA)


def _grey(image: np.ndarray) -> np.ndarray:
    if image.ndim == 3:
        return cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
    if image.dtype != np.uint8:
        raise TypeError("the locator takes uint8 grey images")
    return image


def _face_up(part: PartSpec) -> str:
    """The pose whose silhouette is the part's own, unmirrored outline."""
    if "face_up" in part.poses:
        return "face_up"
    for name, pose in part.poses.items():
        if not pose.mirror and pose.silhouette is None:
            return name
    return next(iter(part.poses))
