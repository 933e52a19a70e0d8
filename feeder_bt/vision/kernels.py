"""The locator's per-blob work compiled (numba): one call a frame instead of a few numpy and
OpenCV calls a blob.

The bench's frames have 4-9 blobs, and each numpy or OpenCV call from Python costs a few µs
here: before these kernels half of the locator's time was that glue between calls
(docs/performance.md, "The floor"). Two kernels do what the glue did:

* ``blob_stats``: for every contour of a frame, its bounding box, area and centroid (the
  polygon moments as ``cv2.moments`` sums them), boundary pixels, centroid in mm and the
  local scale (through the calibration's similarity or its ``PixelGrid`` table), and as
  asked the smoothed length (``chains._smooth_length``'s tours, summed as ``cv2.arcLength``
  sums) and the convex hull (as ``cv2.convexHull``: its vertices, no collinear points) with
  its minimum-area rectangle, area and length.
* ``faces``: for the blobs that need a face, the sub-pixel edge points of their hulls'
  vertices (``Segmenter._edge_points``' rule), those points in mm, and their cut-corner
  signatures (``corners._corner_signatures``' rule); ``signatures`` is that last step alone.

This module imports numba, which costs about 0.3 s: it is imported only when a ``Locator``
is built (``warm``), never by ``feeder --help`` or ``feeder check``. The compiled code is
cached beside this file (``__pycache__``; numba writes each file under a temporary name and
renames it, so processes compiling at once do not clash), or, where that is read-only, in
the user's cache (``NUMBA_CACHE_DIR`` moves it); with no writable place at all the kernels
are compiled in memory each process. tests/test_kernels.py checks each against the OpenCV
call or numpy code it replaced, on random inputs.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit


def _jit(fn=None, **kw):
    if fn is None:
        return lambda f: _jit(f, **kw)
    try:
        return njit(cache=True, nogil=True, **kw)(fn)
    except RuntimeError:            # numba found no writable cache directory
        return njit(nogil=True, **kw)(fn)


_DB1_6 = 0.16666666666666666666666666666667          # cv2.moments' constant
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
        for _ in range(h):                                  # farthest along the edge
            n1 = ahead + 1 if ahead + 1 < h else 0
            if (P[idx[n1], 0] - P[idx[ahead], 0]) * eu + (P[idx[n1], 1] - P[idx[ahead], 1]) * ev <= 0:
                break
            ahead = n1
        if i == 0:
            k = ahead
        for _ in range(h):                                  # farthest from the edge
            n1 = k + 1 if k + 1 < h else 0
            if (P[idx[n1], 1] - P[idx[k], 1]) * eu - (P[idx[n1], 0] - P[idx[k], 0]) * ev <= 0:
                break
            k = n1
        if i == 0:
            back = k
        for _ in range(h):                                  # farthest back along it
            n1 = back + 1 if back + 1 < h else 0
            if (P[idx[n1], 0] - P[idx[back], 0]) * eu + (P[idx[n1], 1] - P[idx[back], 1]) * ev >= 0:
                break
            back = n1
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


# blob_stats' columns
(M00, CU, CV, STEPS, X, Y, SCALE, LENGTH, RECT_W, RECT_H, HULL_AREA, HULL_LEN,
 N_STATS) = range(13)


@_jit
def blob_stats(pts, lens, min_px, full, want_length, want_hull, window, kind, cells, par):
    """Per contour of ``lens[i]`` points (int32 pixels, one after another in pts): its bounding box (u, v, w, h;
    -1 in w when the box is under ``min_px`` pixels: a speck, nothing else measured), the
    ``N_STATS`` columns above (``LENGTH`` onwards only as asked, else NaN), and the hull's
    vertices (indices into pts, ``hull_ends`` per contour)."""
    n = len(lens)
    ends = np.cumsum(lens)
    box = np.empty((n, 4), np.int64)
    st = np.full((n, N_STATS), np.nan)
    hull = np.empty(len(pts) if want_hull else 0, np.int64)
    wide = pts[:, 0].max() - pts[:, 0].min() + 1 if want_hull and len(pts) else 0
    cols = np.empty(2 * wide, np.int64)
    tmp = np.empty(2 * wide + 1, np.int64)
    stack_u = np.empty(2 * wide + 1)
    stack_v = np.empty(2 * wide + 1)
    hull_ends = np.zeros(n, np.int64)
    h = 0
    a = 0
    for i in range(n):
        b = ends[i]
        u0 = u1 = pts[a, 0]
        v0 = v1 = pts[a, 1]
        for j in range(a + 1, b):
            u0 = min(u0, pts[j, 0])
            u1 = max(u1, pts[j, 0])
            v0 = min(v0, pts[j, 1])
            v1 = max(v1, pts[j, 1])
        box[i, 0], box[i, 1], box[i, 2], box[i, 3] = u0, v0, u1 - u0 + 1, v1 - v0 + 1
        if (u1 - u0 + 1) * (v1 - v0 + 1) < min_px:
            box[i, 2] = -1
            hull_ends[i] = h
            a = b
            continue
        # the polygon's moments, summed as cv2.moments sums them (exact on integers)
        a00 = a10 = a01 = 0.0
        pu, pv = float(pts[b - 1, 0]), float(pts[b - 1, 1])
        su = sv = 0.0
        steps = 0
        for j in range(a, b):
            qu, qv = float(pts[j, 0]), float(pts[j, 1])
            dxy = pu * qv - qu * pv
            a00 += dxy
            a10 += dxy * (pu + qu)
            a01 += dxy * (pv + qv)
            su += qu
            sv += qv
            steps += max(abs(int(qu - pu)), abs(int(qv - pv)))
            pu, pv = qu, qv
        if abs(a00) > _FLT_EPSILON:
            sign = 1.0 if a00 > 0 else -1.0
            m00 = abs(a00) * 0.5
            cu = a10 * sign * _DB1_6 / m00
            cv = a01 * sign * _DB1_6 / m00
        else:
            m00 = 0.0
            cu, cv = su / (b - a), sv / (b - a)
        st[i, M00], st[i, CU], st[i, CV] = m00, cu, cv
        st[i, STEPS] = (b - a) if full else (steps if b - a > 1 else 1)
        st[i, X], st[i, Y], st[i, SCALE] = _to_mm(cu, cv, kind, cells, par)
        if want_length:
            st[i, LENGTH] = smooth_length(pts, a, b, window)
        if want_hull:
            k = pixel_hull(pts, a, b, u0, u1 - u0 + 1, cols, tmp, stack_u, stack_v)
            hull[h:h + k] = tmp[:k]
            _hull_stats(pts, hull, h, h + k, st[i])
            h += k
        hull_ends[i] = h
        a = b
    return box, st, hull[:h], hull_ends


@_jit
def _hull_stats(pts, hull, a, b, row):
    """The minimum-area rectangle's sides, the area and length of the hull pts[hull[a:b]]."""
    idx = hull[a:b]
    _, _, _, w, h = min_rect(pts, idx, b - a, _TIE)
    row[RECT_W], row[RECT_H] = w, h
    area = 0.0
    for j in range(b - a):
        p, q = idx[j - 1 if j else b - a - 1], idx[j]
        area += float(pts[p, 0]) * pts[q, 1] - float(pts[q, 0]) * pts[p, 1]
    row[HULL_AREA] = abs(area) * 0.5
    row[HULL_LEN] = _arc(pts, hull, a, b)



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


def warm() -> None:
    """Compile (or load from the cache) every kernel for the argument types the locator
    passes, so that no frame pays for it."""
    pts = np.array([[0, 0], [2, 0], [2, 2], [0, 2]] * 3, np.int32)
    lens = np.array([4, 4, 4], np.int64)
    ends = np.cumsum(lens)
    cells = np.zeros((1, 4, 3))
    par = np.array([1.0, 0.0, 0.0, 1.0, 0.0, 0.0, 1.0])
    _, _, hull, hull_ends = blob_stats(pts, lens, 0.0, True, True, True, 5, SIMILARITY,
                                       cells, par)
    img = np.zeros(9, np.uint8)
    faces(pts, hull, hull_ends, np.array([0], np.int64), img, img, DIFF, 3, 0, True,
          SIMILARITY, cells, par)
    signatures(pts.astype(np.float32), ends, False)
    smooth_length(pts, 0, 4, 5)
    map_points(pts.astype(np.float64), SIMILARITY, cells, par)
    mask = np.zeros((6, 16), np.uint8)
    rois = foreground_rois(mask.view(np.uint64), 6, 16, 1)
    rois = np.array([[0, 6, 0, 8]], np.int64)
    for m in (mask, mask[:, :12]):         # a scratch mask: whole rows, or padded ones
        packed, geo = pack_rois(m, rois, 1)
        clear_mirrors(packed, geo)
    place_contours(pts.copy(), lens, 3, geo, 16)


@_jit
def _lit_rows(words, h):
    """Which rows of a mask (8 pixels a word) have foreground."""
    nw = words.shape[1]
    lit = np.empty(h, np.bool_)
    for v in range(h):
        x = np.uint64(0)
        for k in range(nw):
            x |= words[v, k]
        lit[v] = x != 0
    return lit


@_jit
def _or_rows(words, a, b, acc):
    """``acc``: the OR of rows a..b of a mask (8 pixels a word)."""
    nw = words.shape[1]
    acc[:] = 0
    for r in range(a, b + 1):
        for k in range(nw):
            acc[k] |= words[r, k]


@_jit
def _column_runs(acc, w, gap, margin, v0, v1, res):
    """Append to ``res`` a rectangle (v0, v1, u0, u1) per run of lit columns of ``acc`` (8
    a word), runs parted by more than ``gap`` unlit ones, with ``margin``."""
    c0 = c1 = -1
    for u in range(w + gap + 2):             # the last run is closed past the end
        on = u < w and (acc[u >> 3] >> np.uint64(8 * (u & 7))) & np.uint64(255) != 0
        if c0 >= 0 and u - c1 > gap:         # more than gap columns since the run's last
            res.append((v0, v1, max(c0 - margin, 0), min(c1 + margin + 1, w)))
            c0 = -1
        if on:
            if c0 < 0:
                c0 = u
            c1 = u


@_jit
def foreground_rois(words, h, w, margin):
    """``Segmenter._rois``: rectangles (v0, v1, u0, u1) holding all the foreground of a
    mask (h rows, w columns, given as 8 pixels a word, rows padded with zeros to whole
    words), each with ``margin`` empty pixels (or the image's edge) around it. Rows with
    foreground are cut into bands where more than 2 ``margin`` empty rows part them, then
    each band's columns likewise."""
    gap = 2 * margin
    res = [(0, 0, 0, 0)]
    res.pop()
    acc = np.empty(words.shape[1], np.uint64)
    lit = _lit_rows(words, h)
    v = 0
    while v < h:
        if not lit[v]:
            v += 1
            continue
        a = b = v                            # a band: rows a..b, no gap wider than gap
        v += 1
        while v < h and v - b <= gap:
            if lit[v]:
                b = v
            v += 1
        _or_rows(words, a, b, acc)
        _column_runs(acc, w, gap, margin, max(a - margin, 0), min(b + margin + 1, h), res)
    out = np.empty((len(res), 4), np.int64)
    for i in range(len(res)):
        out[i, 0], out[i, 1], out[i, 2], out[i, 3] = res[i]
    return out


@_jit(inline="always")
def _reflect(i, n):
    """Index i of a line of n pixels, mirrored at its ends without repeating them
    (OpenCV's BORDER_REFLECT_101)."""
    if n == 1:
        return 0
    while i < 0 or i >= n:
        i = -i if i < 0 else 2 * n - 2 - i
    return i


@_jit
def pack_rois(mask, rois, pad):
    """The rectangles ``rois`` (v0, v1, u0, u1) of ``mask`` laid side by side in one image
    (``Segmenter._contours_holes``), each padded by ``pad`` pixels of its own mirror image
    (BORDER_REFLECT_101) on the sides where it meets the image's edge. Returns the image
    and per rectangle: its x there, its padding top, bottom, left, right, its height and
    width there, and the move (du, dv) that takes its pixels back to the frame's."""
    h, w = mask.shape
    n = len(rois)
    geo = np.empty((n, 9), np.int64)
    x = height = 0
    for i in range(n):
        v0, v1, u0, u1 = rois[i, 0], rois[i, 1], rois[i, 2], rois[i, 3]
        top = pad if v0 == 0 else 0
        bottom = pad if v1 == h else 0
        left = pad if u0 == 0 else 0
        right = pad if u1 == w else 0
        sh, sw = v1 - v0 + top + bottom, u1 - u0 + left + right
        geo[i, 0], geo[i, 1], geo[i, 2], geo[i, 3], geo[i, 4] = x, top, bottom, left, right
        geo[i, 5], geo[i, 6], geo[i, 7], geo[i, 8] = sh, sw, u0 - x - left, v0 - top
        x += sw
        height = max(height, sh)
    packed = np.zeros((height, x), np.uint8)
    for i in range(n):
        v0, v1, u0, u1 = rois[i, 0], rois[i, 1], rois[i, 2], rois[i, 3]
        x0, top, left, sh, sw = geo[i, 0], geo[i, 1], geo[i, 3], geo[i, 5], geo[i, 6]
        mirrored = geo[i, 1] + geo[i, 2] + geo[i, 3] + geo[i, 4] > 0
        # unsigned indices: no check for negative ones, so the copy is vectorised
        for r in range(sh):
            dst = np.uintp(r)
            src = np.uintp(v0 + _reflect(r - top, v1 - v0))
            if mirrored:
                for c in range(sw):
                    packed[dst, np.uintp(x0 + c)] = \
                        mask[src, np.uintp(u0 + _reflect(c - left, u1 - u0))]
            else:
                for c in range(sw):
                    packed[dst, np.uintp(x0 + c)] = mask[src, np.uintp(u0 + c)]
    return packed, geo


@_jit
def clear_mirrors(packed, geo):
    """Empty the mirrored padding of ``pack_rois``' rectangles (after the morphology)."""
    for i in range(len(geo)):
        x0, top, bottom, left, right, sh, sw = (geo[i, 0], geo[i, 1], geo[i, 2], geo[i, 3],
                                                 geo[i, 4], geo[i, 5], geo[i, 6])
        if top + bottom + left + right == 0:
            continue
        for r in range(packed.shape[0]):
            row = np.uintp(r)
            if r < top or sh - bottom <= r < sh:
                for c in range(sw):
                    packed[row, np.uintp(x0 + c)] = 0
            else:
                for c in range(left):
                    packed[row, np.uintp(x0 + c)] = 0
                for c in range(sw - right, sw):
                    packed[row, np.uintp(x0 + c)] = 0


@_jit
def place_contours(pts, lens, packed, geo, width):
    """Contours (pts, ``lens[i]`` points each, one after another) back in the frame: the
    first ``packed`` were found in ``pack_rois``' image and move by the (du, dv) of the
    rectangle their first point lies in; then all in the whole frame's ``findContours``
    order (by first point, last found first). Returns the points and lengths in that
    order, each one's index in the input, and the move each input contour got."""
    n = len(lens)
    ends = np.cumsum(lens)
    moved = np.zeros((n, 2), np.int64)
    keys = np.empty(n, np.int64)
    starts = geo[:, 0]
    for i in range(n):
        a = ends[i] - lens[i]
        if i < packed:
            j = np.searchsorted(starts, pts[a, 0], side="right") - 1
            du, dv = geo[j, 7], geo[j, 8]
            moved[i, 0], moved[i, 1] = du, dv
            for q in range(a, ends[i]):
                pts[q, 0] += du
                pts[q, 1] += dv
        keys[i] = -(pts[a, 1] * width + pts[a, 0])
    order = np.argsort(keys)
    out = np.empty_like(pts)
    out_lens = np.empty(n, np.int64)
    m = 0
    for t in range(n):
        i = order[t]
        a = ends[i] - lens[i]
        for q in range(lens[i]):
            out[m + q, 0], out[m + q, 1] = pts[a + q, 0], pts[a + q, 1]
        m += lens[i]
        out_lens[t] = lens[i]
    return out, out_lens, order, moved
