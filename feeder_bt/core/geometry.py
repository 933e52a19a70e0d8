"""Outlines of parts in their stable poses, shared by the simulator and the tools.

An outline is an ``(N, 2)`` float array of mm in the part's frame (origin at the area
centroid, angle 0 as drawn in the scenario). A part with holes (a washer) has several
rings in the one array, parted by a row of NaN: the outer ring first, then each hole
(``rings`` splits them). So an outline still moves, turns and renders as one array; code
that needs one closed polygon takes ``outer``. The locator never sees these: it sees
pixels.
"""

from __future__ import annotations

import math

import cv2
import numpy as np

from feeder_bt.core.model import PartSpec, Shape

DISC_SEGMENTS = 72


_BREAK = np.full((1, 2), np.nan)


def _circle(d: float) -> np.ndarray:
    a = np.linspace(0.0, 2 * math.pi, DISC_SEGMENTS, endpoint=False)
    return np.stack([d / 2.0 * np.cos(a), d / 2.0 * np.sin(a)], axis=1)


def shape_outline(shape: Shape) -> np.ndarray:
    """The shape's rings (outer first, then holes; see the module docstring), centred on
    the area centroid of the region they bound."""
    holes: list[np.ndarray] = []
    if shape.kind == "disc":
        pts = _circle(shape.diameter_mm)
        if shape.hole_mm > 0:
            holes.append(_circle(shape.hole_mm)[::-1])
    elif shape.kind == "rect":
        w, h = shape.size_mm
        pts = np.array([[-w / 2, -h / 2], [w / 2, -h / 2], [w / 2, h / 2], [-w / 2, h / 2]])
    elif shape.kind == "polygon":
        pts = np.asarray(shape.points_mm, dtype=float)
        holes = [np.asarray(h, dtype=float) for h in shape.holes_mm]
    else:
        raise ValueError(f"unknown shape kind {shape.kind!r}")
    out = join_rings([pts, *holes])
    return out - region_centroid(out)


def join_rings(rings_: list[np.ndarray]) -> np.ndarray:
    """Rings (outer first) -> one outline array, parted by NaN rows."""
    if len(rings_) == 1:
        return np.asarray(rings_[0], dtype=float)
    parts: list[np.ndarray] = []
    for r in rings_:
        if parts:
            parts.append(_BREAK)
        parts.append(np.asarray(r, dtype=float).reshape(-1, 2))
    return np.concatenate(parts)


def rings(outline: np.ndarray) -> list[np.ndarray]:
    """An outline's rings: the outer one first, then its holes."""
    nan = np.isnan(outline[:, 0])
    if not nan.any():
        return [outline]
    cuts = nan.nonzero()[0]
    bounds = [-1, *cuts.tolist(), len(outline)]
    return [outline[a + 1:b] for a, b in zip(bounds[:-1], bounds[1:], strict=True) if b > a + 1]


def outer(outline: np.ndarray) -> np.ndarray:
    """The outer ring of an outline (the whole array when it has no holes)."""
    nan = np.isnan(outline[:, 0])
    return outline[:int(nan.argmax())] if nan.any() else outline


def region_centroid(outline: np.ndarray) -> np.ndarray:
    """Area centroid of the region an outline bounds (its holes taken out)."""
    rs = rings(outline)
    if len(rs) == 1:
        return polygon_centroid(rs[0])
    areas = [polygon_area(r) for r in rs]
    weights = np.array([areas[0]] + [-a for a in areas[1:]])
    if abs(weights.sum()) < 1e-12:
        return polygon_centroid(rs[0])
    cents = np.array([polygon_centroid(r) for r in rs])
    return (weights[:, None] * cents).sum(axis=0) / weights.sum()


def polygon_centroid(pts: np.ndarray) -> np.ndarray:
    x, y = pts[:, 0], pts[:, 1]
    xs, ys = np.roll(x, -1), np.roll(y, -1)
    cross = x * ys - xs * y
    area = cross.sum() / 2.0
    if abs(area) < 1e-12:
        return pts.mean(axis=0)
    cx = ((x + xs) * cross).sum() / (6 * area)
    cy = ((y + ys) * cross).sum() / (6 * area)
    return np.array([cx, cy])


def polygon_area(pts: np.ndarray) -> float:
    """Area of a polygon; of an outline with holes, the outer ring's less the holes'."""
    if np.isnan(pts[:, 0]).any():
        rs = rings(pts)
        return polygon_area(rs[0]) - sum(polygon_area(r) for r in rs[1:])
    x, y = pts[:, 0], pts[:, 1]
    return abs(float((x * np.roll(y, -1) - np.roll(x, -1) * y).sum()) / 2.0)


def pose_outline(part: PartSpec, pose: str) -> np.ndarray:
    """The silhouette a part shows from above when lying in ``pose`` (part frame)."""
    p = part.poses[pose]
    pts = shape_outline(p.silhouette) if p.silhouette is not None else shape_outline(part.shape)
    if p.mirror:
        # keep each ring's winding after mirroring, and the outer ring first
        pts = join_rings([r[::-1] * np.array([1.0, -1.0]) for r in rings(pts)])
    return pts


def place_outline(outline: np.ndarray, x: float, y: float, angle_deg: float) -> np.ndarray:
    """Rotate an outline by ``angle_deg`` and move its origin to ``(x, y)``."""
    a = math.radians(angle_deg)
    c, s = math.cos(a), math.sin(a)
    rot = np.array([[c, -s], [s, c]])
    return outline @ rot.T + np.array([x, y])


def circumradius(outline: np.ndarray) -> float:
    """Distance of the outline's farthest point from its origin (its outer ring's)."""
    o = outer(outline)
    return float(np.sqrt((o ** 2).sum(axis=1)).max())


def wrap_deg(a: float, period: float = 360.0) -> float:
    """Angle in (-period/2, period/2]."""
    a = math.fmod(a, period)
    if a > period / 2:
        a -= period
    elif a <= -period / 2:
        a += period
    return a


NEAR_RES_MM = 0.25          # ``near``'s raster pixel
_SHIFT = 4                  # fillPoly fractional bits


def is_convex(ring: np.ndarray) -> bool:
    """Whether a closed ring (no holes) is convex."""
    return bool(cv2.isContourConvex(np.asarray(ring, np.float32).reshape(-1, 1, 2)))


def near(a: np.ndarray, b: np.ndarray, gap_mm: float) -> bool:
    """Whether two closed rings (belt mm, convex or not) overlap or come closer than
    ``gap_mm``: both are drawn at ``NEAR_RES_MM`` in their common box, one thickened by the
    gap, and any shared pixel counts (to within a pixel)."""
    lo = np.maximum(a.min(axis=0), b.min(axis=0)) - gap_mm
    hi = np.minimum(a.max(axis=0), b.max(axis=0)) + gap_mm
    if (hi <= lo).any():
        return False
    w, h = (np.ceil((hi - lo) / NEAR_RES_MM).astype(int) + 1).tolist()
    scale = (1 << _SHIFT) / NEAR_RES_MM
    ma = np.zeros((h, w), np.uint8)
    mb = np.zeros((h, w), np.uint8)
    for ring, m in ((a, ma), (b, mb)):
        cv2.fillPoly(m, [np.round((ring - lo) * scale).astype(np.int32).reshape(-1, 1, 2)], 1,
                     shift=_SHIFT)
    r = max(int(round(gap_mm / NEAR_RES_MM)), 1)
    ma = cv2.dilate(ma, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1, 2 * r + 1)))
    return bool(cv2.countNonZero(cv2.bitwise_and(ma, mb)))
