"""The cut-corner signature of a square with one corner cut: its angle and face.

Used by the locator's ``orientation: cut_corner`` on outlines in mm: each chiral part's
model signature (``_part_signature``) is matched against a blob's (``Locator._faces``)
by ``_orient``, which gives the angle and the face.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from feeder_bt.core.geometry import pose_outline, wrap_deg
from feeder_bt.core.model import PartSpec
from feeder_bt.vision.jit import kernels


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


def _corner_signature(pts: np.ndarray) -> _CornerSignature | None:
    """Cut-corner signature of one closed outline given as points in mm."""
    return _corner_signatures([np.asarray(pts, dtype=np.float32).reshape(-1, 2)])[0]


def _corner_signatures(outlines: list[np.ndarray], hulled: bool = False
                       ) -> list[_CornerSignature | None]:
    """Cut-corner signatures of closed outlines, each given as (n, 2) float32 points in mm
    (at least one point each); ``hulled``: each is already its convex hull's vertices, or
    points close around them (``Locator._faces``: where the edge crosses the level next to
    each pixel of the hull), nothing else inside.

    The minimum-area rectangle gives the angle (mod 90°); the rectangle corner farthest
    from the outline is the cut one; the cut is longer along one side than the other,
    which tells the faces apart. All of it reads only the outline's convex hull (the
    rectangle, the points nearest the rectangle's corners and at the ends of its sides),
    all the outlines in one compiled call (``kernels.signatures``).
    """
    xy = np.ascontiguousarray(np.concatenate(outlines).reshape(-1, 2), dtype=np.float32)
    ends = np.cumsum([len(o) for o in outlines])
    return _signature_rows(kernels().signatures(xy, ends, hulled))


def _signature_rows(rows: np.ndarray) -> list[_CornerSignature | None]:
    """``kernels.signatures``' rows as signatures (None: no cut corner seen)."""
    return [_CornerSignature(corner=(cx, cy), leg=(lx, ly), alpha=a) if ok else None
            for ok, cx, cy, lx, ly, a in rows.tolist()]


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


def _cut_corner(model: _CornerSignature, xy: np.ndarray) -> tuple[float, bool] | None:
    """Angle (deg) and face at which the model outline matches the blob, or None."""
    return _orient(model, _corner_signature(np.asarray(xy, dtype=float).reshape(-1, 2)))


def _part_signature(part: PartSpec) -> _CornerSignature | None:
    """The signature of the part's own, unmirrored outline (``_face_up``): the model."""
    return _corner_signature(_densify(pose_outline(part, _face_up(part))))


def _face_up(part: PartSpec) -> str:
    """The pose whose silhouette is the part's own, unmirrored outline."""
    if "face_up" in part.poses:
        return "face_up"
    for name, pose in part.poses.items():
        if not pose.mirror and pose.silhouette is None:
            return name
    return next(iter(part.poses))
