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
  its minimum-area rectangle, area and length (the mapping, hull and rectangle in
  ``hull_kernels``, which the faces' kernels share).
* ``otsu_level``, ``golden_mask`` / ``golden_threshold``, ``foreground_rois``, ``pack_rois``, ``place_contours``;
  ``packed_morph`` (in ``bit_kernels``: the packing with the opening and closing, a bit a
  pixel) and ``golden_morph`` (the level, mask and ``packed_morph`` in one call)
  (in ``contour_kernels``): Otsu's level of the subsampled difference image, the
  rectangles of foreground, packed, and their contours back in the frame
  (``Segmenter._contours_holes``).
* ``faces`` (in ``face_kernels``): for the blobs that need a face, the sub-pixel edge points of their hulls'
  vertices (``Segmenter._edge_points``' rule), those points in mm, and their cut-corner
  signatures (``corners._corner_signatures``' rule); ``signatures`` is that last step alone.

This module imports numba, which costs about 0.3 s: it is imported only when a ``Locator``
is built (``warm``), never by ``feeder --help`` (``feeder check`` of a scenario builds one
to measure its outlines: ``config.part_checks``). The compiled code is
cached beside this file (``__pycache__``; numba writes each file under a temporary name and
renames it, so processes compiling at once do not clash), or, where that is read-only, in
the user's cache (``NUMBA_CACHE_DIR`` moves it); with no writable place at all the kernels
are compiled in memory each process. tests/vision/test_kernels.py checks each against the OpenCV
call or numpy code it replaced, on random inputs.
"""

from __future__ import annotations

import numpy as np

from feeder_bt.vision.bit_kernels import golden_morph, packed_morph  # noqa: F401
from feeder_bt.vision.contour_kernels import (  # noqa: F401  (the locator reads them all here)
    GOLDEN_MINUS,
    MINUS_GOLDEN,
    PLAIN,
    foreground_rois,
    golden_mask,
    golden_threshold,
    otsu_level,
    pack_rois,
    place_contours,
)
from feeder_bt.vision.face_kernels import (  # noqa: F401  (the locator reads them all here)
    DIFF,
    GOLDEN_DARK,
    GOLDEN_LIGHT,
    PLAIN_DARK,
    PLAIN_LIGHT,
    edge_points,
    faces,
    signatures,
)
from feeder_bt.vision.hull_kernels import (  # noqa: F401  (the locator reads them all here)
    _FLT_EPSILON,
    _TIE,
    SIMILARITY,
    TABLE,
    _arc,
    _to_mm,
    convex_hull,
    map_points,
    min_rect,
    pixel_hull,
    smooth_length,
)
from feeder_bt.vision.kernel_jit import _jit

_DB1_6 = 0.16666666666666666666666666666667          # cv2.moments' constant

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
    for otsu, light in ((True, False), (False, True)):
        golden_mask(mask, mask, 3, light, mask)
        golden_threshold(mask, mask, mask[:2, :4].copy(), 4, otsu, 1.0, light, mask)
        golden_morph(mask, mask, mask[:2, :4].copy(), 4, otsu, 1.0, light, mask, 1,
                     *cross, *cross)
    place_contours(pts.copy(), lens, 3, geo, 16)
