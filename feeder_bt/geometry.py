"""Outlines of parts in their stable poses, shared by the simulator and the tools.

An outline is an ``(N, 2)`` float array of mm in the part's frame (origin at the area
centroid, angle 0 as drawn in the scenario). The locator never sees these: it sees pixels.
"""

from __future__ import annotations

import math

import numpy as np

from .scenario.model import PartSpec, Shape

DISC_SEGMENTS = 72


def shape_outline(shape: Shape) -> np.ndarray:
    if shape.kind == "disc":
        a = np.linspace(0.0, 2 * math.pi, DISC_SEGMENTS, endpoint=False)
        r = shape.diameter_mm / 2.0
        pts = np.stack([r * np.cos(a), r * np.sin(a)], axis=1)
    elif shape.kind == "rect":
        w, h = shape.size_mm
        pts = np.array([[-w / 2, -h / 2], [w / 2, -h / 2], [w / 2, h / 2], [-w / 2, h / 2]])
    elif shape.kind == "polygon":
        pts = np.asarray(shape.points_mm, dtype=float)
    else:
        raise ValueError(f"unknown shape kind {shape.kind!r}")
    return pts - polygon_centroid(pts)


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
    x, y = pts[:, 0], pts[:, 1]
    return abs(float((x * np.roll(y, -1) - np.roll(x, -1) * y).sum()) / 2.0)


def pose_outline(part: PartSpec, pose: str) -> np.ndarray:
    """The silhouette a part shows from above when lying in ``pose`` (part frame)."""
    p = part.poses[pose]
    pts = shape_outline(p.silhouette) if p.silhouette is not None else shape_outline(part.shape)
    if p.mirror:
        pts = pts * np.array([1.0, -1.0])
        pts = pts[::-1].copy()          # keep the winding after mirroring
    return pts


def place_outline(outline: np.ndarray, x: float, y: float, angle_deg: float) -> np.ndarray:
    """Rotate an outline by ``angle_deg`` and move its origin to ``(x, y)``."""
    a = math.radians(angle_deg)
    c, s = math.cos(a), math.sin(a)
    rot = np.array([[c, -s], [s, c]])
    return outline @ rot.T + np.array([x, y])


def circumradius(outline: np.ndarray) -> float:
    return float(np.sqrt((outline ** 2).sum(axis=1)).max())


def wrap_deg(a: float, period: float = 360.0) -> float:
    """Angle in (-period/2, period/2]."""
    a = math.fmod(a, period)
    if a > period / 2:
        a -= period
    elif a <= -period / 2:
        a += period
    return a
