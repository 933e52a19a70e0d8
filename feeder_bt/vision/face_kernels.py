"""Compiled kernels of the faces (numba; ``vision.kernels`` puts them together for the locator): the
sub-pixel edge points of the blobs' pixel hulls (``Segmenter._bright_source``), their
mapping to mm and the cut-corner signatures (``corners._corner_signatures``), all of a
frame's blobs in one call (``Locator._faces``)."""

from __future__ import annotations

import math

import numpy as np

from feeder_bt.vision.hull_kernels import _to_mm, convex_hull, min_rect
from feeder_bt.vision.kernel_jit import _jit

# how ``faces`` reads the image in which parts are bright at a pixel (``Segmenter._diff_at``)
DIFF, GOLDEN_LIGHT, GOLDEN_DARK, PLAIN_LIGHT, PLAIN_DARK = range(5)


@_jit(inline="always")
def _bright(src, golden, mode, at):
    x = np.int64(src[at])
    if mode == DIFF or mode == PLAIN_LIGHT:
        return x
    if mode == PLAIN_DARK:
        return 255 - x
    g = np.int64(golden[at])
    d = x - g if mode == GOLDEN_LIGHT else g - x
    return d if d > 0 else 0


@_jit
def edge_points(pts, hull, hull_ends, sel, src, golden, mode, width, cut, fine):
    """``Segmenter._edge_points`` rule on the hulls of the contours ``sel`` (contour i's
    hull: pts[hull[hull_ends[i - 1]:hull_ends[i]]]): between each vertex and each
    4-neighbour outside the level ``cut``, where the grey (``_bright``, interpolated
    linearly) crosses it; (m, 2) pixels and the ends of each hull's points. If ``fine`` is
    off (no level), or some hull has fewer than 3 such points, the vertices themselves."""
    n = len(sel)
    total = 0
    for s in range(n):
        i = sel[s]
        total += hull_ends[i] - (hull_ends[i - 1] if i else 0)
    out = np.empty((4 * total, 2))
    ends = np.empty(n, np.int64)
    m = 0
    few = not fine
    if fine:
        for s in range(n):
            i = sel[s]
            start = m
            for j in range(hull_ends[i - 1] if i else 0, hull_ends[i]):
                u, v = pts[hull[j], 0], pts[hull[j], 1]
                at = v * width + u
                inside = _bright(src, golden, mode, at)
                if inside <= cut:
                    continue
                for k in range(4):            # the 4-neighbours: u + 1, u - 1, v + 1, v - 1
                    du = 1 if k == 0 else (-1 if k == 1 else 0)
                    dv = 1 if k == 2 else (-1 if k == 3 else 0)
                    nb = _bright(src, golden, mode, at + du + dv * width)
                    if nb <= cut:
                        t = (inside - (cut + 0.5)) / (inside - nb)
                        out[m, 0] = u + t * du
                        out[m, 1] = v + t * dv
                        m += 1
            if m - start < 3:
                few = True
                break
            ends[s] = m
    if few:
        m = 0
        for s in range(n):
            i = sel[s]
            for j in range(hull_ends[i - 1] if i else 0, hull_ends[i]):
                out[m, 0], out[m, 1] = pts[hull[j], 0], pts[hull[j], 1]
                m += 1
            ends[s] = m
    return out[:m], ends


_TOL = 1.5                            # mm: a point this near a side is on it
_SQRT2 = math.sqrt(2.0)


@_jit
def signatures(xy, ends, hulled):
    """``corners._corner_signatures`` of the outlines xy[ends[i - 1]:ends[i]] (mm; float32
    values): per outline a row valid (1/0), corner x, y, leg x, y, alpha (rad)."""
    n = len(ends)
    out = np.zeros((n, 6))
    idx = np.empty(2 * len(xy) + 1, np.int64)
    qx = np.empty(len(xy))
    qy = np.empty(len(xy))
    a = 0
    for i in range(n):
        b = ends[i]
        P = xy[a:b]
        k = convex_hull(P, idx)
        cx, cy, al, w, h = min_rect(P, idx, k, 0.0)
        hx, hy = 0.5 * w, 0.5 * h
        ca, sa = math.cos(al), math.sin(al)
        m = b - a if hulled else k
        # each point in the rectangle's frame, and its squared distance to the nearest
        # point of each corner (+, +), (-, +), (-, -), (+, -)
        n0 = n1 = n2 = n3 = np.inf
        for j in range(m):
            t = j if hulled else idx[j]
            du, dv = float(P[t, 0]) - cx, float(P[t, 1]) - cy
            x = du * ca + dv * sa
            y = dv * ca - du * sa
            qx[j], qy[j] = x, y
            xp, xm, yp, ym = (x - hx) ** 2, (x + hx) ** 2, (y - hy) ** 2, (y + hy) ** 2
            n0 = min(n0, xp + yp)
            n1 = min(n1, xm + yp)
            n2 = min(n2, xm + ym)
            n3 = min(n3, xp + ym)
        # the corner farthest from the outline is the cut one
        cxs, cys, far = 1.0, 1.0, n0
        if n1 > far:
            cxs, cys, far = -1.0, 1.0, n1
        if n2 > far:
            cxs, cys, far = -1.0, -1.0, n2
        if n3 > far:
            cxs, cys, far = 1.0, -1.0, n3
        sx = np.sign(hx * cxs)
        sy = np.sign(hy * cys)
        top = right = -np.inf
        for j in range(m):                            # cut corner now at (+, +)
            fx, fy = qx[j] * sx, qy[j] * sy
            if abs(fy - hy) < _TOL:
                top = max(top, fx)
            if abs(fx - hx) < _TOL:
                right = max(right, fy)
        a = b
        if top == -np.inf or right == -np.inf:
            continue
        out[i, 0] = 1.0
        vx, vy = sx / _SQRT2, sy / _SQRT2
        out[i, 1], out[i, 2] = vx * ca - vy * sa, vx * sa + vy * ca
        if hx - top >= hy - right:                    # the cut is longer along x
            out[i, 3], out[i, 4] = -sx * ca, -sx * sa
        else:
            out[i, 3], out[i, 4] = sy * sa, -sy * ca
        out[i, 5] = al
    return out


@_jit
def faces(pts, hull, hull_ends, sel, src, golden, mode, width, cut, fine, kind, cells, par):
    """``edge_points`` of the hulls of contours ``sel``, mapped to mm (``_to_mm``, rounded
    to float32 as the signature always took them), and their ``signatures``."""
    uv, ends = edge_points(pts, hull, hull_ends, sel, src, golden, mode, width, cut, fine)
    xy = np.empty((len(uv), 2), np.float32)
    for j in range(len(uv)):
        x, y, _ = _to_mm(uv[j, 0], uv[j, 1], kind, cells, par)
        xy[j, 0], xy[j, 1] = x, y
    return signatures(xy, ends, True)
