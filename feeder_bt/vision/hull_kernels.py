"""Compiled kernels (numba) of a contour's geometry that the blobs' and the faces' kernels
share: the mapping of pixels to mm (through the calibration's similarity or its
``PixelGrid`` table), the smoothed length, the convex hull and the minimum-area
rectangle. ``vision.kernels`` puts them together with the rest for the locator."""

from __future__ import annotations

import math

import numpy as np

from feeder_bt.vision.kernel_jit import _jit

_FLT_EPSILON = 1.1920928955078125e-07

# mapping kinds (``Calibration._kernel_table``, ``PixelGrid._kernel_table``)
SIMILARITY, TABLE = 0, 1


@_jit(inline="always")
def _to_mm(u, v, kind, cells, par):
    """Pixel (u, v) -> belt (x, y) mm and mm per px: the similarity (par: its matrix by rows,
    origin, scale) or a ``PixelGrid`` table (par: origin u, v; 1 / step; last cell u, v;
    cells per row), as their numpy code computes it."""
    if kind == SIMILARITY:
        return u * par[0] + v * par[1] + par[4], u * par[2] + v * par[3] + par[5], par[6]
    gu = (u - par[0]) * par[2]
    gv = (v - par[1]) * par[2]
    cu = min(max(math.floor(gu), 0.0), par[3])
    cv = min(max(math.floor(gv), 0.0), par[4])
    fu = gu - cu
    fv = gv - cv
    fuv = fu * fv
    k = int(cu) + int(cv) * int(par[5])
    out = np.empty(3)
    for j in range(3):
        out[j] = cells[k, 0, j] + fu * cells[k, 1, j] + fv * cells[k, 2, j] \
            + fuv * cells[k, 3, j]
    return out[0], out[1], out[2]


@_jit
def map_points(uv, kind, cells, par):
    """(n, 2) float pixels -> (n, 3): x, y mm and mm per px."""
    n = uv.shape[0]
    out = np.empty((n, 3))
    for i in range(n):
        out[i, 0], out[i, 1], out[i, 2] = _to_mm(uv[i, 0], uv[i, 1], kind, cells, par)
    return out


@_jit(inline="always")
def _f32_step(du, dv):
    """One step's length as ``cv2.arcLength`` takes it: in float32, summed in float64."""
    return float(np.sqrt(np.float32(du * du + dv * dv)))


@_jit
def _arc(pts, idx, a, b):
    """``cv2.arcLength`` of the closed polygon pts[idx[a:b]]."""
    p = idx[b - 1]
    pu, pv = float(pts[p, 0]), float(pts[p, 1])
    s = 0.0
    for j in range(a, b):
        q = idx[j]
        qu, qv = float(pts[q, 0]), float(pts[q, 1])
        s += _f32_step(qu - pu, qv - pv)
        pu, pv = qu, qv
    return s


@_jit
def smooth_length(pts, a, b, window):
    """``chains._smooth_length`` of the closed contour pts[a:b]: the length of the polygon
    visiting it ``window`` points at a time (one tour, or ``window`` tours), / window."""
    n = b - a
    if n < 2 * window:
        idx = np.arange(a, b)
        return _arc(pts, idx, 0, n)
    if n % window:
        idx = a + np.arange(n) * window % n
        return _arc(pts, idx, 0, n) / window
    m = n // window
    total = 0.0
    idx = np.empty(m, np.int64)
    for t in range(window):
        for j in range(m):
            idx[j] = a + t + j * window
        total += _arc(pts, idx, 0, m)
    return total / window


@_jit
def _monotone(P, order, m, out):
    """Andrew's monotone chain over the points P[order[:m]] (sorted by u, then v): the
    convex hull's vertices counter-clockwise, collinear and repeated points left out (as
    ``cv2.convexHull`` leaves them), as indices into P written to ``out`` (room for
    2 m + 1); returns how many."""
    if m == 0:
        return 0
    k = 0
    for t in range(2 * m - 1):
        if t < m:
            i = order[t]
            lo = 2
        else:                                               # the upper chain, back
            i = order[2 * m - 2 - t]
            if t == m:
                lo = k + 1
        iu, iv = float(P[i, 0]), float(P[i, 1])
        while k >= lo:
            au, av = float(P[out[k - 2], 0]), float(P[out[k - 2], 1])
            bu, bv = float(P[out[k - 1], 0]), float(P[out[k - 1], 1])
            if (bu - au) * (iv - av) - (bv - av) * (iu - au) > 0:
                break
            k -= 1
        out[k] = i
        k += 1
    k = max(k - 1, 1)                                       # the first point again
    if k == 2 and P[out[0], 0] == P[out[1], 0] and P[out[0], 1] == P[out[1], 1]:
        k = 1
    return k


@_jit
def convex_hull(P, out):
    """The convex hull of the points P ((n, 2)) as indices into P (``_monotone``)."""
    n = len(P)
    order = np.argsort(P[:, 0])
    for t in range(1, n):               # ties in u by v (few: the sort leaves them near)
        i = order[t]
        s = t
        while s > 0 and P[order[s - 1], 0] == P[i, 0] and P[order[s - 1], 1] > P[i, 1]:
            order[s] = order[s - 1]
            s -= 1
        order[s] = i
    return _monotone(P, order, n, out)


@_jit(inline="always")
def _push(pu, pv, i, su, sv, out, k, lo):
    """Andrew's step: pop the chain's last points while they do not turn left, then push
    point i (pu, pv); returns the chain's new length."""
    while k >= lo and (su[k - 1] - su[k - 2]) * (pv - sv[k - 2]) \
            - (sv[k - 1] - sv[k - 2]) * (pu - su[k - 2]) <= 0:
        k -= 1
    su[k], sv[k], out[k] = pu, pv, i
    return k + 1


@_jit
def pixel_hull(pts, a, b, u0, width, cols, out, su, sv):
    """The convex hull of the pixel contour pts[a:b], whose columns are u0 .. u0 + width - 1,
    as ``_monotone`` gives it, in linear time: of each column only the bottom pixel can be
    a vertex of the lower chain and the top one of the upper chain, and taking them column
    by column sorts them. Indices into pts; ``cols`` is scratch room for 2 width, ``out``,
    ``su`` and ``sv`` for 2 width + 1."""
    lo = cols[:width]
    hi = cols[width:2 * width]
    lo[:] = -1
    hi[:] = -1
    for j in range(a, b):
        c = pts[j, 0] - u0
        v = pts[j, 1]
        if lo[c] < 0 or v < pts[lo[c], 1]:
            lo[c] = j
        if hi[c] < 0 or v > pts[hi[c], 1]:
            hi[c] = j
    last = width - 1
    k = 0
    for c in range(width + 1):                 # lower chain, then the last column's top
        i = lo[c] if c < width else hi[last]
        if i < 0 or (c == width and pts[i, 1] == pts[lo[last], 1]):
            continue
        k = _push(float(pts[i, 0]), float(pts[i, 1]), i, su, sv, out, k, 2)
    top = k + 1
    for c in range(last - 1, -2, -1):          # upper chain, back to the first point
        i = hi[c] if c >= 0 else lo[0]
        if i < 0:
            continue
        k = _push(float(pts[i, 0]), float(pts[i, 1]), i, su, sv, out, k, top)
    k = max(k - 1, 1)                          # the first point again
    if k == 2 and pts[out[0], 0] == pts[out[1], 0] and pts[out[0], 1] == pts[out[1], 1]:
        k = 1
    return k


@_jit(inline="always")
def _walk(P, idx, h, j, a, b):
    """From vertex j of the convex polygon P[idx[:h]], onwards while each step goes further
    in the direction (a, b): where a caliper of ``min_rect`` comes to rest."""
    for _ in range(h):
        n1 = j + 1 if j + 1 < h else 0
        if (P[idx[n1], 0] - P[idx[j], 0]) * a + (P[idx[n1], 1] - P[idx[j], 1]) * b <= 0:
            break
        j = n1
    return j


_TIE = 1e-6         # areas this close (relative) are one: cv2.minAreaRect works in float32


@_jit
def min_rect(P, idx, h, tie):
    """The minimum-area rectangle of the convex polygon P[idx[:h]] (counter-clockwise, as
    ``_monotone`` gives it), by rotating calipers: centre u, v, the angle (rad) of its side
    ``w``, and the sides w, h. One side lies along an edge of the polygon. Of rectangles
    whose areas tie (to ``tie``, relative), the one whose side is nearest the u axis
    turning from it (mod 90°), as ``cv2.minAreaRect``, which turns its calipers from there,
    mostly takes it (it compares float32 areas): with ``_TIE`` a digitised disc's aspect
    is OpenCV's (1.02, not 1.00) on every blob of the bench's frames."""
    if h == 1:
        return float(P[idx[0], 0]), float(P[idx[0], 1]), 0.0, 0.0, 0.0
    if h == 2:
        pu, pv = float(P[idx[0], 0]), float(P[idx[0], 1])
        eu, ev = float(P[idx[1], 0]) - pu, float(P[idx[1], 1]) - pv
        return pu + 0.5 * eu, pv + 0.5 * ev, math.atan2(ev, eu), math.hypot(eu, ev), 0.0
    areas = np.empty(h)
    far = np.empty((h, 3), np.int64)            # each edge's calipers: ahead, across, back
    ahead = k = back = 0
    for i in range(h):
        pu, pv = float(P[idx[i], 0]), float(P[idx[i], 1])
        i1 = i + 1 if i + 1 < h else 0
        eu, ev = float(P[idx[i1], 0]) - pu, float(P[idx[i1], 1]) - pv
        if i == 0:
            ahead = i1
        ahead = _walk(P, idx, h, ahead, eu, ev)             # farthest along the edge
        if i == 0:
            k = ahead
        k = _walk(P, idx, h, k, -ev, eu)                    # farthest from the edge
        if i == 0:
            back = k
        back = _walk(P, idx, h, back, -eu, -ev)             # farthest back along it
        along = (P[idx[ahead], 0] - P[idx[back], 0]) * eu + (P[idx[ahead], 1] - P[idx[back], 1]) * ev
        across = (P[idx[k], 1] - pv) * eu - (P[idx[k], 0] - pu) * ev
        areas[i] = along * across / (eu * eu + ev * ev)
        far[i, 0], far[i, 1], far[i, 2] = ahead, k, back
    least = areas.min() * (1.0 + tie)
    pick, turn = 0, 10.0
    for i in range(h):
        if areas[i] <= least:
            i1 = i + 1 if i + 1 < h else 0
            t = math.atan2(float(P[idx[i1], 1]) - P[idx[i], 1],
                           float(P[idx[i1], 0]) - P[idx[i], 0]) % (0.5 * math.pi)
            if t < turn:
                pick, turn = i, t
    i = pick
    i1 = i + 1 if i + 1 < h else 0
    pu, pv = float(P[idx[i], 0]), float(P[idx[i], 1])
    eu, ev = float(P[idx[i1], 0]) - pu, float(P[idx[i1], 1]) - pv
    ln = math.sqrt(eu * eu + ev * ev)
    c, s = eu / ln, ev / ln
    ahead, k, back = far[i, 0], far[i, 1], far[i, 2]
    hi = (P[idx[ahead], 0] - pu) * c + (P[idx[ahead], 1] - pv) * s
    lo = (P[idx[back], 0] - pu) * c + (P[idx[back], 1] - pv) * s
    ht = (P[idx[k], 1] - pv) * c - (P[idx[k], 0] - pu) * s
    ma, mb = 0.5 * (hi + lo), 0.5 * ht
    return pu + ma * c - mb * s, pv + ma * s + mb * c, math.atan2(s, c), hi - lo, ht
