"""The OpenCV locator: a grey image -> poses of singulated parts in the belt frame.

It sees only pixels, the cell's calibration and the recipe — never ground truth.
Pipeline: golden-image subtraction (dark parts become bright), threshold, morphology,
external contours; blobs touching the image border or smaller than ``min_area_mm2`` are
rejected; every feature of ``FEATURES`` is measured in mm (mm² for areas) through the
calibration, corrected for pixelisation so that it is close to the physical value (a
50.8 mm disc: ~2030 mm², circularity ~0.99); the first recipe class whose ranges all hold
names the part and pose. Position is the blob's area centroid, which is the part frame's
origin (``geometry``).
Merged (touching) parts fall outside every class and are rejected, so they are never
picked.

Recipe semantics worth knowing:

* ``threshold.method``: ``fixed`` (``value`` grey levels of difference), ``otsu`` (Otsu's
  level, but never below ``value``, so an empty belt does not turn noise into blobs), or
  ``adaptive`` (``block_px``, ``c`` above the local mean).
* ``orientation``: ``none`` -> 0; ``principal_axis`` -> the long axis from moments, in
  (-90, 90]; ``cut_corner`` -> for classes with ``mirrored`` set, the angle (and face) at
  which the part's ``face_up`` outline matches the blob, in (-180, 180]; other classes
  fall back to the principal axis when elongated, else 0.

Each call of ``locate`` uses only local state (the golden image is read, never written),
so one ``Locator`` may serve several threads.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import cv2
import numpy as np

from ..geometry import pose_outline, wrap_deg
from ..scenario.model import PartSpec, VisionClass, VisionRecipe
from .calibration import Calibration
from .features import FEATURES

_FINE = 4                      # upsampling of the sub-pixel outline used for orientation
_ELONGATED = 1.3               # aspect above which a symmetric blob has a principal axis


@dataclass
class Detection:
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


# ------------------------------------------------------------------- cut-corner signature


@dataclass
class _CornerSignature:
    """Where a square's cut corner is and which way its long cut leg runs.

    ``corner``: unit vector from the rectangle centre towards the cut corner; ``leg``: unit
    vector along the side on which the cut is longer, pointing away from the corner.
    ``alpha``: the minimum-area rectangle's angle (rad, mod 90°).
    """

    corner: tuple[float, float]
    leg: tuple[float, float]
    alpha: float


def _from_frame(vx: float, vy: float, c: float, s: float) -> tuple[float, float]:
    """A vector in the rectangle's frame (cos ``c``, sin ``s`` of its angle) -> outline frame."""
    return vx * c - vy * s, vx * s + vy * c


def _sign(v: float) -> float:
    return 1.0 if v > 0 else -1.0 if v < 0 else 0.0


_SQRT2 = math.sqrt(2.0)


def _corner_signature(pts: np.ndarray) -> _CornerSignature | None:
    """Cut-corner signature of a closed outline given as dense points in mm.

    The minimum-area rectangle gives the angle (mod 90°); the rectangle corner farthest
    from the outline is the cut one; the cut is longer along one side than the other,
    which tells the faces apart. Works on the x and y columns separately and on Python
    floats for the 2-vectors: this runs once per chiral blob, where numpy's per-call cost
    dominated (the arithmetic, and so the answer, is the same as the matrix form).
    """
    (cx, cy), (w, h), a = cv2.minAreaRect(pts.astype(np.float32))
    alpha = math.radians(a)
    hx, hy = w / 2.0, h / 2.0
    c, s = math.cos(alpha), math.sin(alpha)
    dx, dy = pts[:, 0] - cx, pts[:, 1] - cy
    qx, qy = dx * c + dy * s, -dx * s + dy * c       # the outline in the rectangle's frame
    # squared distance of the nearest outline point to each rectangle corner (a row each)
    d2 = (qx - np.array([[hx], [-hx], [-hx], [hx]])) ** 2
    d2 += (qy - np.array([[hy], [hy], [-hy], [-hy]])) ** 2
    k = int(np.argmax(d2.min(axis=1)))
    sx, sy = _sign((hx, -hx, -hx, hx)[k]), _sign((hy, hy, -hy, -hy)[k])
    fx, fy = qx * sx, qy * sy                 # cut corner now at (+, +)
    tol = 1.5
    top = fx[np.abs(fy - hy) < tol]
    right = fy[np.abs(fx - hx) < tol]
    if len(top) == 0 or len(right) == 0:
        return None
    leg_x = hx - float(top.max())             # cut length along the side parallel to x
    leg_y = hy - float(right.max())
    corner = _from_frame(sx / _SQRT2, sy / _SQRT2, c, s)
    leg = _from_frame(-sx, 0.0, c, s) if leg_x >= leg_y else _from_frame(0.0, -sy, c, s)
    return _CornerSignature(corner=corner, leg=leg, alpha=alpha)


def _densify(outline: np.ndarray, step: float = 0.25) -> np.ndarray:
    out = []
    n = len(outline)
    for i in range(n):
        a, b = outline[i], outline[(i + 1) % n]
        m = max(int(math.ceil(np.hypot(*(b - a)) / step)), 1)
        t = np.arange(m)[:, None] / m
        out.append(a + t * (b - a))
    return np.concatenate(out)


def _cross(a: tuple[float, float], b: tuple[float, float]) -> float:
    return float(a[0] * b[1] - a[1] * b[0])


def _angle(v: tuple[float, float]) -> float:
    return math.atan2(v[1], v[0])


# ---------------------------------------------------------------------------- locator


class Locator:
    """Finds parts in backlit images with one recipe; see the module docstring."""

    def __init__(self, recipe: VisionRecipe, parts: dict[str, PartSpec],
                 calibration: Calibration) -> None:
        self.recipe = recipe
        self.parts = parts
        self.calibration = calibration
        self._golden: np.ndarray | None = None
        for cls in recipe.classes:
            for name in cls.ranges:
                if name not in FEATURES:
                    raise ValueError(f"class {cls.part}/{cls.pose}: unknown feature {name!r}")
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
        # bands of the image this far clear of foreground are left empty by them.
        reach = sum(2 * (k.shape[0] // 2) for k in (self._open, self._close) if k is not None)
        self._margin = reach + 1
        self._below: np.ndarray | None = None     # golden - level: fixed threshold in one pass

    # -------------------------------------------------------------- images

    def set_golden(self, image: np.ndarray) -> None:
        """Remember the cleared belt; later frames are compared against it."""
        self._golden = _grey(image).copy()
        th = self.recipe.threshold
        self._below = None
        if th.method == "fixed" and 0 <= math.floor(th.value) < 255:
            # golden - img > t  <=>  img < golden - t (saturated at 0: never below 0)
            self._below = cv2.subtract(self._golden, math.floor(th.value))

    def foreground(self, image: np.ndarray) -> np.ndarray:
        """Binary mask (0/255) of what the recipe considers parts."""
        return self._segment(_grey(image))[0]

    def _segment(self, img: np.ndarray) -> tuple[np.ndarray, np.ndarray, float | None]:
        """Mask, the difference image it was cut from, and the level (None: adaptive)."""
        mask, diff, level = self._threshold(img)
        return self._morph(mask), self._diff(img) if diff is None else diff, level

    def _diff(self, img: np.ndarray) -> np.ndarray:
        """Dark parts on a bright belt -> bright: the golden image minus the frame."""
        golden = self._golden
        if self.recipe.golden_image and golden is not None:
            return cv2.subtract(golden, img)
        return cv2.bitwise_not(img)

    def _threshold(self, img: np.ndarray) -> tuple[np.ndarray, np.ndarray | None, float | None]:
        """The thresholded mask (before morphology), the difference image (None if it was
        not needed: ``_diff`` makes it) and the level (None: adaptive)."""
        th = self.recipe.threshold
        if th.method == "fixed" and self.recipe.golden_image and self._below is not None \
                and self._below.shape == img.shape:
            # the same mask as subtract-then-threshold, in one pass over the frame
            return cv2.compare(img, self._below, cv2.CMP_LT), None, float(th.value)
        diff = self._diff(img)
        if th.method == "fixed":
            level: float | None = float(th.value)
            _, mask = cv2.threshold(diff, th.value, 255, cv2.THRESH_BINARY)
        elif th.method == "otsu":
            level, mask = cv2.threshold(diff, 0, 255, cv2.THRESH_BINARY | cv2.THRESH_OTSU)
            if level < th.value:
                level = float(th.value)
                _, mask = cv2.threshold(diff, th.value, 255, cv2.THRESH_BINARY)
        elif th.method == "adaptive":
            level = None
            block = max(3, int(th.block_px) | 1)
            mask = cv2.adaptiveThreshold(diff, 255, cv2.ADAPTIVE_THRESH_MEAN_C,
                                         cv2.THRESH_BINARY, block, -th.c)
        else:
            raise ValueError(f"unknown threshold method {th.method!r}")
        return mask, diff, level

    def _morph(self, mask: np.ndarray) -> np.ndarray:
        if self._open is not None:
            mask = cv2.morphologyEx(mask, cv2.MORPH_OPEN, self._open)
        if self._close is not None:
            mask = cv2.morphologyEx(mask, cv2.MORPH_CLOSE, self._close)
        return mask

    def _contours(self, mask: np.ndarray) -> list[np.ndarray]:
        """External contours of the opened and closed ``mask``, in ``findContours``' order.

        Most of a frame is empty belt, so the morphology and the contour search run only on
        bands of rows (cut to their columns) around the foreground, each with a margin of
        empty pixels wider than the morphology reaches: inside a band every pixel comes out
        as on the whole frame, outside the bands nothing does. ``findContours`` lists the
        contours last-found first, so the bands are searched bottom-up.
        """
        h, w = mask.shape
        m = self._margin
        rows = np.flatnonzero(cv2.reduce(mask, 1, cv2.REDUCE_SUM, dtype=cv2.CV_32S))
        if len(rows) == 0:
            return []
        cuts = np.flatnonzero(np.diff(rows) > 2 * m)
        firsts = [int(rows[0])] + rows[cuts + 1].tolist()
        lasts = rows[cuts].tolist() + [int(rows[-1])]
        out: list[np.ndarray] = []
        for a, b in zip(reversed(firsts), reversed(lasts), strict=True):
            cols = np.flatnonzero(cv2.reduce(mask[a:b + 1], 0, cv2.REDUCE_SUM,
                                             dtype=cv2.CV_32S))
            r0, r1 = max(a - m, 0), min(b + m + 1, h)
            c0, c1 = max(int(cols[0]) - m, 0), min(int(cols[-1]) + m + 1, w)
            band = self._morph(mask[r0:r1, c0:c1])
            cs, _ = cv2.findContours(band, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE,
                                     offset=(c0, r0))
            out.extend(cs)
        return out

    def locate(self, image: np.ndarray) -> LocateResult:
        """Find, measure and classify every blob in ``image``."""
        t0 = time.perf_counter()
        img = _grey(image)
        mask, diff, level = self._threshold(img)
        contours = self._contours(mask)
        h, w = img.shape[:2]
        parts: list[Detection] = []
        rejected: list[Detection] = []
        kept: list[np.ndarray] = []
        for c, box, length in self._blobs(contours):
            bu, bv, bw, bh = box
            det, xy = self._measure(c, length)
            if bu <= 0 or bv <= 0 or bu + bw >= w or bv + bh >= h:
                det.reason = "touches border"
            elif det.features["area_mm2"] < self.recipe.min_area_mm2:
                det.reason = "too small"
            else:
                if diff is None and self._signatures:    # the fine outline reads it
                    diff = self._diff(img)
                self._classify(det, c, xy, diff, level, box)
            (rejected if det.reason else parts).append(det)
            kept.append(c)
        ms = (time.perf_counter() - t0) * 1e3
        return LocateResult(parts=parts, rejected=rejected, ms=ms, contours=kept)

    def measure_blobs(self, image: np.ndarray) -> list[Detection]:
        """Every blob's features, unclassified, measured exactly as ``locate`` measures them.

        For tools that tune a recipe (``feeder recipe suggest``): one feature extractor for
        tuning and feeding. ``reason`` marks blobs ``locate`` would reject before
        classification ("touches border", "too small"); ``part`` is always None.
        """
        img = _grey(image)
        contours = self._contours(self._threshold(img)[0])
        h, w = img.shape[:2]
        out: list[Detection] = []
        for c, (bu, bv, bw, bh), length in self._blobs(contours):
            det, _ = self._measure(c, length)
            if bu <= 0 or bv <= 0 or bu + bw >= w or bv + bh >= h:
                det.reason = "touches border"
            elif det.features["area_mm2"] < self.recipe.min_area_mm2:
                det.reason = "too small"
            out.append(det)
        return out

    # -------------------------------------------------------------- per blob

    def _blobs(self, contours: list[np.ndarray]
               ) -> list[tuple[np.ndarray, tuple[int, int, int, int], float]]:
        """The contours worth reporting (not specks), with their bounding boxes and
        smoothed lengths in px (``_smooth_lengths``: all of a frame's in one pass)."""
        min_px = self.recipe.min_area_mm2 / self.calibration.mm2_per_px2
        kept = []
        for c in contours:
            box = cv2.boundingRect(c)
            if box[2] * box[3] >= min_px * 0.5:
                kept.append((c, box))
        lengths = _smooth_lengths([c for c, _ in kept])
        return [(c, box, length) for (c, box), length in zip(kept, lengths, strict=True)]

    def _measure(self, contour: np.ndarray, smooth_length: float
                 ) -> tuple[Detection, np.ndarray | None]:
        """Features and centroid of one contour, and the contour in mm if already needed.
        ``smooth_length`` is the contour's ``_smooth_lengths`` (px).

        The calibration is a similarity (scale, rotation, reflection), so lengths scale by
        ``mm_per_px``, areas by its square and the ratios and Hu invariants not at all:
        shape features are measured on the pixel contour (cheaper) and scaled. Angles are
        only ever taken from the contour mapped to mm, which is mapped only for blobs whose
        angle is asked for (``_contour_mm``): most blobs never need it.
        """
        cal = self.calibration
        s, s2 = cal.mm_per_px, cal.mm2_per_px2
        mom = cv2.moments(contour)
        m00 = mom["m00"]
        area = abs(m00)
        uv = contour.reshape(-1, 2)
        # The contour runs through the centres of the boundary pixels; by Pick's theorem
        # the blob's pixel count is the polygon's area + boundary pixels / 2 + 1.
        area_px = area + 0.5 * len(uv) + 1.0
        # A pixel staircase is up to 8 % longer than the edge it follows: measure the
        # contour smoothed along itself instead, then move it out the half pixel to the
        # blob's edge (which adds 2·π·0.5 to a closed convex outline).
        perim = smooth_length + math.pi
        if area > 0:
            cu, cv = mom["m10"] / m00, mom["m01"] / m00
            # the first two Hu invariants, as cv2.HuMoments computes them (same operations)
            n20, n02, n11 = mom["nu20"], mom["nu02"], mom["nu11"]
            hu1, hu2 = n20 + n02, (n20 - n02) * (n20 - n02) + 4 * n11 * n11
        else:
            cu, cv = (float(v) for v in uv.mean(axis=0))
            hu1 = hu2 = 0.0
        (_, _), (rw, rh), _ = cv2.minAreaRect(contour)
        rw, rh = rw + 1.0, rh + 1.0
        hull = cv2.convexHull(contour)
        hull_area = cv2.contourArea(hull) + 0.5 * cv2.arcLength(hull, True) + 1.0
        feats = {
            "area_mm2": area_px * s2,
            "perimeter_mm": perim * s,
            "circularity": 4 * math.pi * area_px / (perim * perim) if perim > 0 else 0.0,
            "aspect": max(rw, rh) / min(rw, rh) if min(rw, rh) > 0 else 0.0,
            "rectangularity": area_px / (rw * rh) if rw * rh > 0 else 0.0,
            "solidity": min(area_px / hull_area, 1.0) if hull_area > 0 else 0.0,
            "hu1": float(hu1),
            "hu2": float(hu2),
        }
        x, y = cal.px_to_mm(np.array([[cu, cv]]))[0]
        det = Detection(part=None, pose=None, pickable=False, x_mm=float(x), y_mm=float(y),
                        angle_deg=0.0, u_px=float(cu), v_px=float(cv), features=feats)
        xy = None
        if self.recipe.orientation == "principal_axis":
            xy = self._contour_mm(contour)
            det.angle_deg = self._principal_angle(cv2.moments(xy))
        return det, xy

    def _contour_mm(self, contour: np.ndarray) -> np.ndarray:
        """The pixel contour mapped to belt mm (float32), for angles."""
        return self.calibration.px_to_mm(contour.reshape(-1, 2)).astype(np.float32)

    def _fine_contour(self, diff: np.ndarray, level: float | None,
                      box: tuple[int, int, int, int]) -> np.ndarray | None:
        """The blob's outline in mm to a fraction of a pixel, for orientation.

        A binary contour moves in whole pixels, which limits the angle of a near-axis edge
        to about 1°. Interpolating the difference image at ``_FINE``x and cutting it at
        the same level puts the edge where the grey levels say it is. ``box`` is the
        blob's bounding box (u, v, width, height) in pixels.
        """
        if level is None:
            return None
        h, w = diff.shape
        bu, bv, bw, bh = box
        u0, v0 = max(bu - 2, 0), max(bv - 2, 0)
        u1, v1 = min(bu + bw + 2, w), min(bv + bh + 2, h)
        k = _FINE
        up = cv2.resize(diff[v0:v1, u0:u1], ((u1 - u0) * k, (v1 - v0) * k),
                        interpolation=cv2.INTER_LINEAR)
        _, m = cv2.threshold(up, level, 255, cv2.THRESH_BINARY)
        # SIMPLE keeps every vertex of the staircase: the hull and the extremes are intact
        cs, _ = cv2.findContours(m, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
        if not cs:
            return None
        best = cs[0] if len(cs) == 1 else max(cs, key=cv2.contourArea)
        # (p + 0.5) / k - 0.5 + origin, folded: exact in floating point for k a power of 2
        uv = best.reshape(-1, 2) * (1.0 / k) + np.array([u0 + (0.5 / k - 0.5),
                                                       v0 + (0.5 / k - 0.5)])
        return self.calibration.px_to_mm(uv)

    @staticmethod
    def _principal_angle(mom: dict[str, float]) -> float:
        a = 0.5 * math.atan2(2 * mom["mu11"], mom["mu20"] - mom["mu02"])
        return wrap_deg(math.degrees(a), 180.0)

    def _classify(self, det: Detection, contour: np.ndarray, xy: np.ndarray | None,
                  diff: np.ndarray | None, level: float | None,
                  box: tuple[int, int, int, int]) -> None:
        """First class whose ranges (and face, for chiral parts) fit; else a reason.

        The contour in mm (``xy``, None if not mapped yet) and the fine outline are made
        only when an angle or a face is asked for.
        """
        feats = det.features
        matches = [c for c in self.recipe.classes if _in_ranges(c, feats)]
        if not matches:
            det.reason = "touching parts / no class"
            return
        chosen: VisionClass | None = None
        faces: dict[str, tuple[float, bool] | None] = {}    # part -> (angle, mirrored)
        for cls in matches:
            if cls.mirrored is None:
                chosen = cls
                det.angle_deg = self._symmetric_angle(det, contour, xy)
                break
            sig = self._signatures.get(cls.part) if self.recipe.orientation == "cut_corner" \
                else None
            if sig is None:
                chosen = cls                  # no way to tell the faces apart: trust the class
                break
            if cls.part not in faces:
                fxy = self._fine_contour(diff, level, box) if diff is not None else None
                if fxy is None:
                    fxy = xy if xy is not None else self._contour_mm(contour)
                faces[cls.part] = self._cut_corner(sig, fxy)
            oriented = faces[cls.part]
            if oriented is None:
                continue
            angle, mirrored = oriented
            feats["mirrored"] = 1.0 if mirrored else 0.0
            if mirrored == cls.mirrored:
                chosen = cls
                det.angle_deg = angle
                break
        if chosen is None:
            det.reason = "no class (face)"
            return
        det.part, det.pose, det.pickable = chosen.part, chosen.pose, chosen.pickable

    def _symmetric_angle(self, det: Detection, contour: np.ndarray,
                         xy: np.ndarray | None) -> float:
        """Angle of a class without a face to tell: its long axis if it has one, else 0."""
        o = self.recipe.orientation
        if o == "none":
            return 0.0
        if o == "principal_axis" or det.features["aspect"] > _ELONGATED:
            return self._principal_angle(cv2.moments(
                xy if xy is not None else self._contour_mm(contour)))
        return 0.0

    @staticmethod
    def _cut_corner(model: _CornerSignature, xy: np.ndarray) -> tuple[float, bool] | None:
        """Angle (deg) and face at which the model outline matches the blob, or None."""
        obs = _corner_signature(np.asarray(xy, dtype=float).reshape(-1, 2))
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


def _smooth_lengths(contours: list[np.ndarray], window: int = 5) -> list[float]:
    """Length of each closed pixel contour after a circular moving average of its points.

    All of a frame's contours go through one set of array operations (one per contour
    cost more than the arithmetic): each is padded with its own wrap-around, the running
    sums run over all of them, and each length is summed over its own slice. The running
    sums are exact integers, so every window mean, difference and length is the same
    float as when each contour is done on its own.
    """
    out = [0.0] * len(contours)
    h = window // 2
    pieces: list[np.ndarray] = []
    starts: list[int] = []
    sizes: list[int] = []
    at = 0
    for i, c in enumerate(contours):
        uv = c.reshape(-1, 2)
        n = len(uv)
        if n < 2 * window:
            out[i] = float(cv2.arcLength(uv.astype(np.float32), True))
            continue
        pieces += [uv[-h - 1:], uv, uv[:h]]
        starts.append(at)
        sizes.append(n)
        at += n + window
    if not starts:
        return out
    c = np.concatenate(pieces).cumsum(axis=0)
    sm = (c[window:] - c[:-window]) / window      # contour j's means: sm[start_j + i]
    d = np.empty_like(sm)                         # sm[i + 1] - sm[i], closing back to sm[0]
    np.subtract(sm[1:], sm[:-1], out=d[:-1])
    first = np.array(starts)
    last = first + np.array(sizes) - 1
    d[last] = sm[first] - sm[last]
    step = np.hypot(d[:, 0], d[:, 1])
    j = 0
    for i, cnt in enumerate(contours):
        if len(cnt) >= 2 * window:
            out[i] = float(step[starts[j]:starts[j] + sizes[j]].sum())
            j += 1
    return out


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


def _in_ranges(cls: VisionClass, feats: dict[str, float]) -> bool:
    for name, (lo, hi) in cls.ranges.items():
        v = feats.get(name)
        if v is None or not (lo <= v <= hi):
            return False
    return True
