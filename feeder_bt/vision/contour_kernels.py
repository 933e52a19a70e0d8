"""Compiled kernels of the segmentation (numba; see ``vision.kernels``, which imports them):
the rectangles of foreground in a mask, their packing into one image with mirrors at the
image's edges, and the contours found there back in the frame, in the whole frame's order
(``Segmenter._contours_holes``)."""

from __future__ import annotations

import numpy as np

from .jit import _jit


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
