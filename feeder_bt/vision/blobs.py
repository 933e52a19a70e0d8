"""Blobs: what one contour of the foreground measures, in the belt frame.

Every blob gets its area (mm², corrected for pixelisation by Pick's theorem) and centroid
from the contour's moments (``find_blobs``); its other features (``features.FEATURES``)
are measured a group at a time, when asked for (``measure_feature``), so the locator's
cascade measures only what its checks need. Nothing here knows the recipe's classes.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from feeder_bt.core.geometry import wrap_deg
from feeder_bt.vision.chains import WINDOW, Contours, _boundary_steps, _full_chain, _smooth_length
from feeder_bt.vision.corners import _CornerSignature
from feeder_bt.vision.features import GROUP_OF
from feeder_bt.vision.jit import kernels
from feeder_bt.vision.pixels import Calibration, PixelGrid

# a similarity's table for ``kernels.blob_stats`` when only the hull is wanted
_SIMILARITY = (0, np.zeros((1, 4, 3)), np.array([1.0, 0.0, 0.0, 1.0, 0.0, 0.0, 1.0]))


@dataclass(slots=True)
class Detection:
    """One blob: its class (None if rejected, with ``reason``), pose in the belt frame and
    in pixels, and the features measured on the way (see ``vision.locator``)."""

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
    # the grip offered (``PartSpec.pick``): its point's offset from (x_mm, y_mm), belt mm
    grip_dx_mm: float = 0.0
    grip_dy_mm: float = 0.0
    grip_deg: float = 0.0      # and its turn from angle_deg


class Blob:
    """One contour on its way through the cascade: what has been measured so far."""

    __slots__ = ("_contour", "box", "area_px", "det", "full", "length", "faced", "face",
                 "oriented", "holes", "scale", "stats", "frame", "index")

    def __init__(self, contour: np.ndarray | None, box: tuple[int, int, int, int],
                 area_px: float, det: Detection, full: bool,
                 holes: list[np.ndarray] | None = None) -> None:
        self._contour = contour           # None: its frame's points, sliced when asked
        self.holes = holes                # its hole contours (None: not looked for)
        self.full = full                  # every boundary pixel (else the chain's corners)
        self.box = box                    # bounding box u, v, width, height
        self.area_px = area_px            # pixel count (Pick's theorem on the contour)
        self.det = det
        self.scale: float | None = None   # mm per px where it lies (``find_blobs``)
        self.length: float | None = None  # smoothed contour length, px (``_smooth_length``)
        self.faced = False                # ``face`` measured (``Locator._faces``)
        self.face: _CornerSignature | None = None   # the cut-corner signature of its outline
        # angle, face by the part (cut_corner) or by the outline or moment model's key
        # (``Locator._models``); None: no face; a str: why not (outline, moment)
        self.oriented: dict[str, tuple[float, bool] | str | None] = {}
        # ``kernels.blob_stats``' row, and the frame's arrays it came with (``Frame``) and
        # its index there: its hull's vertices for the faces
        self.stats: list[float] = []
        self.frame: Frame | None = None
        self.index = 0

    @property
    def contour(self) -> np.ndarray:
        """(n, 1, 2) int32, whole-frame pixels: a view of its frame's points, made the
        first time it is asked for (most blobs of most frames never are)."""
        c = self._contour
        if c is None:
            c = self._contour = self.frame.contours.contour(self.index)
        return c


class Frame:
    """What ``kernels.blob_stats`` measured of one call's contours, kept for the faces:
    all the points (int32, ``(n, 2)``), the contours themselves (``chains.Contours`` over
    those points) and the hulls' vertices (indices, ends per contour; empty if hulls were
    not asked for)."""

    __slots__ = ("pts", "hull", "hull_ends", "contours", "grey")

    def __init__(self, contours: Contours, hull: np.ndarray, hull_ends: np.ndarray,
                 grey: np.ndarray | None = None) -> None:
        self.pts, self.hull, self.hull_ends = contours.pts, hull, hull_ends
        self.contours = contours
        self.grey = grey              # the frame (grey), for ``grey_mean`` and ``grey_std``


def find_blobs(contours: list[np.ndarray], shape: tuple[int, int], calibration: Calibration,
               min_area_mm2: float, full: bool = True,
               holes: list[list[np.ndarray]] | None = None,
               mapping: Calibration | PixelGrid | None = None,
               length: bool = False, hulls: bool = False,
               min_hole_mm2: float = 0.0, grey: np.ndarray | None = None) -> list[Blob]:
    """The contours worth reporting (not specks), measured as far as every blob is: area,
    centroid (mm), the border and size rules (``reason`` "touches border", "too small").

    ``shape``: the frame's (height, width). ``full``: the contours have every boundary
    pixel (else only the chain's corners). ``holes``: each contour's hole contours, if they
    were looked for. The centroids go to mm through ``mapping`` (the calibration's
    ``PixelGrid`` for this image size; default the calibration itself). ``length``, ``hulls``:
    also measure every blob's smoothed length (``full`` contours only), its convex hull and
    minimum-area rectangle now, in the same compiled pass (``kernels.blob_stats``) — what
    the recipe's classes or faces will ask of most blobs; ``measure_feature`` measures them
    one blob at a time otherwise. ``grey``: the frame the contours were found in, for the
    features read from its pixels (``features.PIXEL_FEATURES``).

    The centroid is the blob's area centroid with its holes (of at least ``min_hole_mm2``)
    taken out, the part frame's origin, when its holes were looked for; else the filled
    outline's (the same for a part without holes).
    """
    if not contours:
        return []
    h, w = shape
    s2 = calibration.mm2_per_px2
    min_px = 0.5 * min_area_mm2 / s2
    k = kernels()
    given = not isinstance(contours, Contours)       # else already one array
    if given:
        pts = np.concatenate(contours).reshape(-1, 2)
        lens = np.fromiter(map(len, contours), np.int64, len(contours))
    else:
        pts, lens = contours.pts, contours.lens
    kind, cells, par = (mapping or calibration)._kernel_table()
    boxes, stats, hull, hull_ends = k.blob_stats(
        pts, lens, min_px, full, length and full, hulls,
        WINDOW, kind, cells, par)
    frame = Frame(Contours(pts, lens) if given else contours, hull, hull_ends, grey)
    # a lens or a tilted camera: the scale where each blob lies (a few per mille from the
    # calibration's mm_per_px over the window), for areas and lengths
    local = not calibration.linear
    blobs: list[Blob] = []
    for i, (box, row) in enumerate(zip(boxes.tolist(), stats.tolist(), strict=True)):
        bu, bv, bw, bh = box
        if bw < 0:                          # a speck
            continue
        # The contour runs through the centres of the boundary pixels; by Pick's theorem
        # the blob's pixel count is the polygon's area + boundary pixels / 2 + 1.
        area_px = row[k.M00] + 1.0 + 0.5 * row[k.STEPS]
        sc = row[k.SCALE]
        area = area_px * sc * sc if local else area_px * s2
        reason = "touches border" if bu <= 0 or bv <= 0 or bu + bw >= w or bv + bh >= h \
            else ("too small" if area < min_area_mm2 else "")
        x, y, cu, cv = row[k.X], row[k.Y], row[k.CU], row[k.CV]
        if holes is not None and holes[i]:
            cu, cv, moved = _region_centroid(row[k.M00], cu, cv, holes[i],
                                             min_hole_mm2 / s2)
            if moved:
                x, y = (mapping or calibration).px_to_mm(np.array([[cu, cv]]))[0].tolist()
        det = Detection(None, None, False, x, y, 0.0, cu, cv, {"area_mm2": area}, reason)
        b = Blob(contours[i] if given else None, tuple(box), area_px, det, full,
                 None if holes is None else holes[i])
        if local:
            b.scale = sc
        if row[k.LENGTH] == row[k.LENGTH]:          # measured (not NaN)
            b.length = row[k.LENGTH]
        b.stats, b.frame, b.index = row, frame, i
        blobs.append(b)
    return blobs


def _region_centroid(m00: float, cu: float, cv: float, holes: list[np.ndarray],
                     min_px: float) -> tuple[float, float, bool]:
    """The centroid (px) of the outline's polygon less its holes' of at least ``min_px``
    (smaller ones are specks), and whether any was taken out: a part's holes move its
    area centroid off the filled outline's (a lever with bores at one end: millimetres)."""
    a, su, sv = m00, m00 * cu, m00 * cv
    moved = False
    for h in holes:
        mom = cv2.moments(h)
        ah = mom["m00"]
        if ah <= 0 or ah < min_px:
            continue
        a -= ah
        su -= mom["m10"]
        sv -= mom["m01"]
        moved = True
    if not moved or a <= 0:
        return cu, cv, False
    return su / a, sv / a, True


def _hull_stats(b: Blob) -> list[float]:
    """The blob's stats row with its hull's columns (measured now if ``find_blobs`` was not
    asked for hulls)."""
    k = kernels()
    if b.stats[k.RECT_W] != b.stats[k.RECT_W]:          # NaN: not measured yet
        one = Contours(np.ascontiguousarray(b.contour.reshape(-1, 2)),
                       np.array([len(b.contour)], dtype=np.int64))
        _, stats, hull, hull_ends = k.blob_stats(
            one.pts, one.lens, 0.0, b.full, False, True, WINDOW, *_SIMILARITY)
        b.stats = b.stats[:k.RECT_W] + stats[0, k.RECT_W:].tolist()
        b.frame, b.index = Frame(one, hull, hull_ends), 0
    return b.stats


def measure_feature(b: Blob, name: str, calibration: Calibration,
                    min_hole_mm2: float) -> float:
    """One feature of the blob, measuring its group (``features.GROUPS``) if not yet.

    The calibration is a similarity (scale, rotation, reflection), so lengths scale by
    ``mm_per_px``, areas by its square and the ratios and Hu invariants not at all:
    shape features are measured on the pixel contour (cheaper) and scaled.
    ``min_hole_mm2``: smaller holes are not counted.
    """
    feats = b.det.features
    v = feats.get(name)
    if v is not None:
        return v
    s = b.scale or calibration.mm_per_px
    area_px = b.area_px
    group = GROUP_OF[name]
    if group == GROUP_OF["holes"]:
        # A hole contour runs through the blob's pixels around the hole: by Pick's
        # theorem the hole's pixel count is the polygon's area - boundary pixels / 2 + 1.
        if b.holes is None:
            raise RuntimeError("hole features asked of a blob whose holes were not found")
        s2 = s * s
        steps = _boundary_steps(b.holes, b.full)
        areas = [(abs(cv2.contourArea(k)) - 0.5 * n + 1.0) * s2
                 for k, n in zip(b.holes, steps, strict=True)]
        big = [a for a in areas if a >= min_hole_mm2]
        feats["holes"] = float(len(big))
        feats["hole_area_mm2"] = float(sum(big))
    elif group == GROUP_OF["hu1"]:
        # the first two Hu invariants, as cv2.HuMoments computes them (same operations)
        mom = cv2.moments(b.contour)
        if mom["m00"] != 0:
            n20, n02, n11 = mom["nu20"], mom["nu02"], mom["nu11"]
            feats["hu1"] = float(n20 + n02)
            feats["hu2"] = float((n20 - n02) * (n20 - n02) + 4 * n11 * n11)
        else:
            feats["hu1"] = feats["hu2"] = 0.0
    elif group == GROUP_OF["perimeter_mm"]:
        if b.length is None:
            c = b.contour
            b.length = _smooth_length(c if b.full else _full_chain(c))
        # A pixel staircase is up to 8 % longer than the edge it follows: measure the
        # contour smoothed along itself instead, then move it out the half pixel to the
        # blob's edge (which adds 2·π·0.5 to a closed convex outline).
        perim = b.length + math.pi
        feats["perimeter_mm"] = perim * s
        feats["circularity"] = (4 * math.pi * area_px / (perim * perim)
                                if perim > 0 else 0.0)
    elif group == GROUP_OF["aspect"]:
        # the minimum-area rectangle of the hull (the contour's), as cv2.minAreaRect
        k = kernels()
        row = _hull_stats(b)
        rw, rh = row[k.RECT_W] + 1.0, row[k.RECT_H] + 1.0
        feats["aspect"] = max(rw, rh) / min(rw, rh) if min(rw, rh) > 0 else 0.0
        feats["rectangularity"] = area_px / (rw * rh) if rw * rh > 0 else 0.0
    elif group == GROUP_OF["solidity"]:
        k = kernels()
        row = _hull_stats(b)
        # cv2.contourArea and cv2.arcLength of the hull
        hull_area = row[k.HULL_AREA] + 0.5 * row[k.HULL_LEN] + 1.0
        feats["solidity"] = min(area_px / hull_area, 1.0) if hull_area > 0 else 0.0
    elif group == GROUP_OF["grey_mean"]:
        grey = b.frame.grey if b.frame is not None else None
        if grey is None:
            raise RuntimeError("grey features asked of a blob found without its frame")
        u, v, w, h = b.box
        mask = np.zeros((h, w), np.uint8)
        cv2.drawContours(mask, [b.contour], -1, 255, thickness=cv2.FILLED, offset=(-u, -v))
        if b.holes:
            cv2.drawContours(mask, b.holes, -1, 0, thickness=cv2.FILLED, offset=(-u, -v))
        mean, std = cv2.meanStdDev(grey[v:v + h, u:u + w], mask=mask)
        feats["grey_mean"], feats["grey_std"] = float(mean[0, 0]), float(std[0, 0])
    return feats[name]


def contour_mm(b: Blob, calibration: Calibration | PixelGrid) -> np.ndarray:
    """The pixel contour mapped to belt mm (float32), for angles (through the calibration
    or its ``PixelGrid``)."""
    return calibration.px_to_mm(b.contour.reshape(-1, 2)).astype(np.float32)


def principal_angle(mom: dict[str, float]) -> float:
    """The long axis of a shape from its moments, deg in (-90, 90]."""
    a = 0.5 * math.atan2(2 * mom["mu11"], mom["mu20"] - mom["mu02"])
    return wrap_deg(math.degrees(a), 180.0)
