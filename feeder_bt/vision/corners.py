"""The cut-corner signature of a square with one corner cut: its angle and face.

Used by the locator's ``orientation: cut_corner`` on outlines in mm: each chiral part's
model signature (``_part_signature``) is matched against a blob's (``Locator._faces``)
by ``_orient``, which gives the angle and the face.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from ..geometry import pose_outline, wrap_deg
from ..scenario.model import PartSpec


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


_SQRT2 = math.sqrt(2.0)


def _corner_signature(pts: np.ndarray) -> _CornerSignature | None:
    """Cut-corner signature of one closed outline given as points in mm."""
    return _corner_signatures([np.asarray(pts, dtype=np.float32).reshape(-1, 2)])[0]


_CORNER_X = np.array([1.0, -1.0, -1.0, 1.0])   # the minimum-area rectangle's corners,
_CORNER_Y = np.array([1.0, 1.0, -1.0, -1.0])   # in half-sides, in cv2.boxPoints' turn


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
    and all the hulls go through one set of array operations (numpy's per-call cost
    dominates when done one by one; each point gathers its outline's row once).
    """
    hulls = outlines if hulled else [cv2.convexHull(o).reshape(-1, 2) for o in outlines]
    n = len(hulls)
    counts = [len(hl) for hl in hulls]
    # per outline: centre, angle, half-sides
    par = np.array([(cx, cy, a, w, h) for (cx, cy), (w, h), a in map(cv2.minAreaRect, hulls)]
                   ).reshape(n, 5)
    par[:, 2] = np.radians(par[:, 2])
    par[:, 3:] *= 0.5
    seg = np.repeat(np.arange(n), counts)                       # each point's outline
    starts = np.cumsum([0] + counts[:-1])
    ps = par[seg]                                               # its outline's, a row each
    z = np.concatenate(hulls).astype(np.float64).view(np.complex128).ravel()
    q = (z - (ps[:, 0] + 1j * ps[:, 1])) * np.exp(-1j * ps[:, 2])   # in the rectangle's frame
    hx, hy = ps[:, 3], ps[:, 4]
    qx, qy = q.real, q.imag
    # squared distance of each point to each rectangle corner (a column each, in
    # _CORNER_X / _CORNER_Y's turn), the nearest point's per outline, the farthest corner
    xp, xm, yp, ym = (qx - hx) ** 2, (qx + hx) ** 2, (qy - hy) ** 2, (qy + hy) ** 2
    k = np.minimum.reduceat(np.stack([xp + yp, xm + yp, xm + ym, xp + ym], axis=1),
                            starts).argmax(axis=1)
    sx = np.sign(par[:, 3] * _CORNER_X[k])
    sy = np.sign(par[:, 4] * _CORNER_Y[k])
    fx, fy = qx * sx[seg], qy * sy[seg]                   # cut corner now at (+, +)
    tol = 1.5
    # the far end of the side parallel to x (y) short of the cut: the top (right) side's
    # points within tol of it, their largest x (y); -inf if it has none
    top = np.maximum.reduceat(np.where(np.abs(fy - hy) < tol, fx, -np.inf), starts)
    right = np.maximum.reduceat(np.where(np.abs(fx - hx) < tol, fy, -np.inf), starts)
    out: list[_CornerSignature | None] = []
    for (_, _, aj, hxj, hyj), sxj, syj, tj, rj in zip(par.tolist(), sx.tolist(), sy.tolist(),
                                                      top.tolist(), right.tolist(),
                                                      strict=True):
        if tj == -math.inf or rj == -math.inf:
            out.append(None)
            continue
        cj, sj = math.cos(aj), math.sin(aj)
        leg_x = hxj - tj                     # cut length along the side parallel to x
        leg_y = hyj - rj
        corner = _from_frame(sxj / _SQRT2, syj / _SQRT2, cj, sj)
        leg = (_from_frame(-sxj, 0.0, cj, sj) if leg_x >= leg_y
               else _from_frame(0.0, -syj, cj, sj))
        out.append(_CornerSignature(corner=corner, leg=leg, alpha=aj))
    return out


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
