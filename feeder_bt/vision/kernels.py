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
* ``otsu_level``, ``foreground_rois``, ``pack_rois``, ``place_contours``; ``packed_morph`` (in ``bit_kernels``: the packing with the opening
  and closing, a bit a pixel)
  (in ``contour_kernels``): Otsu's level of the subsampled difference image, the
  rectangles of foreground, packed, and their contours back in the frame
  (``Segmenter._contours_holes``).
* ``faces`` (in ``face_kernels``): for the blobs that need a face, the sub-pixel edge points of their hulls'
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

from feeder_bt.vision.bit_kernels import packed_morph  # noqa: F401
from feeder_bt.vision.contour_kernels import (  # noqa: F401  (the locator reads them all here)
    GOLDEN_MINUS,
    MINUS_GOLDEN,
    PLAIN,
    foreground_rois,
    otsu_level,
    pack_rois,
    place_contours,
)
from feeder_bt.vision.jit import _jit

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



# the faces' kernels use this module's mapping, hull and rectangle: imported last
from feeder_bt.vision.face_kernels import (  # noqa: E402, F401  (the locator reads them all here)
    DIFF,
    GOLDEN_DARK,
    GOLDEN_LIGHT,
    PLAIN_DARK,
    PLAIN_LIGHT,
    edge_points,
    faces,
    signatures,
)


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
    otsu_level(mask, mask[:2, :4].copy(), 4, GOLDEN_MINUS)   # C order, as the locator's
    rois = foreground_rois(mask.view(np.uint64), 6, 16, 1)
    rois = np.array([[0, 6, 0, 8]], np.int64)
    for m in (mask, mask[:, :12]):         # a scratch mask: whole rows, or padded ones
        packed, geo = pack_rois(m, rois, 1)
    cross = np.array([-1, 0, 0, 0, 1], np.int64), np.array([0, -1, 0, 1, 0], np.int64)
    packed_morph(mask.view(np.uint64), 6, 12, 1, *cross, *cross)
    place_contours(pts.copy(), lens, 3, geo, 16)
