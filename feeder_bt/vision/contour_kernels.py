"""Compiled kernels of the segmentation (numba; see ``vision.kernels``, which imports them):
Otsu's level of a difference image's subsample, the rectangles of foreground in a mask,
their packing into one image with mirrors at the image's edges (for asymmetric kernels:
``bit_kernels.packed_morph`` packs for the others), and the contours found there back in
the frame, in the whole frame's order (``Segmenter._contours_holes``)."""

from __future__ import annotations

import math

import numpy as np

from feeder_bt.vision.kernel_jit import _jit

_ALL = np.uint64(0xFFFFFFFFFFFFFFFF)
_FLT_EPSILON = 1.1920928955078125e-07

# what ``otsu_level`` reads: the image, the image minus the golden image (light parts), or
# the golden image minus the image (dark parts), each saturated at 0 as ``cv2.subtract``
PLAIN, MINUS_GOLDEN, GOLDEN_MINUS = 0, 1, 2


@_jit
def otsu_level(img, golden, step, mode):
    """Otsu's level (``cv2.threshold``'s ``THRESH_OTSU`` on 8-bit images: the first level
    of greatest between-class variance, in the same double arithmetic) of the difference
    image sampled at every ``step``-th pixel of every ``step``-th row (``segment.subsample``).

    ``golden``: the golden image sampled likewise (its rows and columns bound the sample),
    read as ``mode`` says. One pass over the sampled pixels, with no copy of the strided
    sample and no sample-sized difference image: the two cost OpenCV more than the
    histogram (the first read of a frame's rows)."""
    # four histograms, a pixel's column picking one: most samples are the belt, a few
    # grey levels, and one histogram's count of a level must wait for its last one (one
    # pass of squares' samples took 28 us so, 16 us with four)
    hists = np.zeros((4, 256), np.int64)
    rows, cols = golden.shape
    for r in range(rows):
        f = img[np.uintp(r * step)]
        g = golden[np.uintp(r)]
        for c in range(cols):
            v = np.int64(f[np.uintp(c * step)])
            if mode == MINUS_GOLDEN:
                v -= np.int64(g[np.uintp(c)])
            elif mode == GOLDEN_MINUS:
                v = np.int64(g[np.uintp(c)]) - v
            hists[np.uintp(c & 3), np.uintp(max(v, 0))] += 1
    hist = hists[0] + hists[1] + hists[2] + hists[3]
    scale = 1.0 / (rows * cols)
    mu = 0.0
    for i in range(256):
        mu += i * np.float64(hist[i])
    mu *= scale
    mu1 = q1 = best = 0.0
    level = 0
    for i in range(256):
        p = hist[i] * scale
        mu1 *= q1
        q1 += p
        q2 = 1.0 - q1
        if min(q1, q2) < _FLT_EPSILON or max(q1, q2) > 1.0 - _FLT_EPSILON:
            continue
        mu1 = (mu1 + i * p) / q1
        mu2 = (mu - q1 * mu1) / q2
        sigma = q1 * q2 * (mu1 - mu2) * (mu1 - mu2)
        if sigma > best:
            best, level = sigma, i
    return float(level)


@_jit
def golden_mask(img, golden, t, light, mask):
    """The mask (0/255, into ``mask``'s first w columns) where ``img`` is below the golden
    image less t (dark parts; the subtraction saturated at 0, as
    ``cv2.compare(img, cv2.subtract(golden, t), CMP_LT)``), or above it plus t (light
    parts; saturated at 255). t from 0 to 255.

    One pass reading the frame and the golden image: no golden image moved by the level
    to make, keep or read (Otsu's level wanders over a dozen values from frame to frame).
    Bytes throughout (the saturation as a comparison, not in wider integers), so the
    compiler vectorises it: as fast as ``cv2.compare`` against a moved image."""
    h, w = img.shape
    tt = np.uint8(t)
    top = np.uint8(255 - t)
    on, off = np.uint8(255), np.uint8(0)
    # unsigned indices: no check for negative ones, so the loops vectorise
    for v in range(h):
        a, g, m = img[np.uintp(v)], golden[np.uintp(v)], mask[np.uintp(v)]
        if light:
            for u in range(w):
                x, y = a[np.uintp(u)], g[np.uintp(u)]
                m[np.uintp(u)] = on if (y <= top) & (x > np.uint8(y + tt)) else off
        else:
            for u in range(w):
                x, y = a[np.uintp(u)], g[np.uintp(u)]
                m[np.uintp(u)] = on if (y > tt) & (x < np.uint8(y - tt)) else off


@_jit
def golden_threshold(img, golden, golden_small, step, otsu, value, light, mask):
    """The mask of a frame against its golden image (``golden_mask``, into ``mask``) at
    the level ``value``, or with ``otsu`` at Otsu's level of the sampled difference
    (``otsu_level``, ``golden_small`` the golden image's sample at ``step``) never below
    ``value``; returns the level. The one rule ``Segmenter._threshold`` and
    ``bit_kernels.golden_morph`` both follow: the mask cut at the level's whole part."""
    level = value
    if otsu:
        level = max(otsu_level(img, golden_small, step,
                               MINUS_GOLDEN if light else GOLDEN_MINUS), value)
    golden_mask(img, golden, min(math.floor(level), 255), light, mask)
    return level


@_jit
def _lit_rows(words, v0, v1, u0, u1, lit):
    """``lit[v - v0]``: whether row v of a mask (8 pixels a word) has foreground in columns
    u0..u1 - 1. (Unsigned indices: no check for negative ones, so the loops vectorise.)"""
    k0, k1 = np.uintp(u0 >> 3), np.uintp((u1 - 1) >> 3)
    m0 = _ALL << np.uint64(8 * (u0 & 7))
    m1 = _ALL >> np.uint64(8 * (7 - ((u1 - 1) & 7)))
    if k0 == k1:
        m0 &= m1
        m1 = np.uint64(0)
    for v in range(v0, v1):
        row = words[np.uintp(v)]
        x = (row[k0] & m0) | (row[k1] & m1)
        for k in range(k0 + np.uintp(1), k1):
            x |= row[k]
        lit[np.uintp(v - v0)] = x != 0


@_jit
def _lit_columns(words, v0, v1, u0, u1, acc, lit):
    """``lit[u - u0]``: whether column u of a mask (8 pixels a word) has foreground in rows
    v0..v1 - 1 (``acc``: scratch, a row of words)."""
    k0, k1 = np.uintp(u0 >> 3), np.uintp(((u1 - 1) >> 3) + 1)
    for k in range(k0, k1):
        acc[k] = 0
    for v in range(v0, v1):
        row = words[np.uintp(v)]
        for k in range(k0, k1):
            acc[k] |= row[k]
    for u in range(u0, u1):
        lit[np.uintp(u - u0)] = (acc[np.uintp(u >> 3)] >> np.uint64(8 * (u & 7))) \
            & np.uint64(255) != 0


@_jit
def _runs(lit, n, gap, starts, ends):
    """The runs of ``lit[:n]`` parted by more than ``gap`` unlit places: how many, their
    first and last places in ``starts``, ``ends``."""
    k = 0
    first = last = -1
    for i in range(n):
        if not lit[i]:
            continue
        if first >= 0 and i - last > gap:
            starts[k], ends[k] = first, last
            k += 1
            first = -1
        if first < 0:
            first = i
        last = i
    if first >= 0:
        starts[k], ends[k] = first, last
        k += 1
    return k


@_jit
def foreground_rois(words, h, w, margin):
    """``Segmenter._rois``: rectangles (v0, v1, u0, u1) holding all the foreground of a
    mask (h rows, w columns, given as 8 pixels a word, rows padded with zeros to whole
    words), each with ``margin`` empty pixels (or the image's edge) around it.

    Cut as an XY-cut: a rectangle's rows with foreground are cut where more than
    2 ``margin`` empty rows part them, each piece's columns likewise, and so on, each
    piece trimmed to its foreground, until neither way cuts. So foreground in two
    rectangles is more than 2 ``margin`` apart along a row or a column, and a rectangle is
    no taller or wider than its own foreground (a band's rows cut only once, then its
    columns, left a short part as tall as the tallest beside it: more pixels to pack,
    open, close and search)."""
    gap = 2 * margin
    res = [(0, 0, 0, 0)]
    res.pop()
    n = max(h, w)
    acc = np.empty(words.shape[1], np.uint64)
    lit = np.empty(n, np.bool_)
    starts = np.empty(n, np.int64)
    ends = np.empty(n, np.int64)
    # (v0, v1, u0, u1, axis: 0 rows / 1 columns, whether the other way did not cut)
    stack = [(0, h, 0, w, 0, 0)]
    while len(stack):
        v0, v1, u0, u1, axis, stuck = stack.pop()
        if axis == 0:
            _lit_rows(words, v0, v1, u0, u1, lit)
            k = _runs(lit, v1 - v0, gap, starts, ends)
        else:
            _lit_columns(words, v0, v1, u0, u1, acc, lit)
            k = _runs(lit, u1 - u0, gap, starts, ends)
        if k == 1 and stuck:
            if axis == 0:
                v0, v1 = v0 + starts[0], v0 + ends[0] + 1
            else:
                u0, u1 = u0 + starts[0], u0 + ends[0] + 1
            res.append((max(v0 - margin, 0), min(v1 + margin, h), max(u0 - margin, 0),
                        min(u1 + margin, w)))
            continue
        for i in range(k - 1, -1, -1):         # the first piece on top: cut first
            if axis == 0:
                stack.append((v0 + starts[i], v0 + ends[i] + 1, u0, u1, 1, 1 if k == 1 else 0))
            else:
                stack.append((v0, v1, u0 + starts[i], u0 + ends[i] + 1, 0, 1 if k == 1 else 0))
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
def roi_geometry(rois, h, w, pad):
    """Where ``pack_rois`` lays the rectangles ``rois`` of an h x w image (padded by
    ``pad`` where they meet its edge): per rectangle its x there, its padding top, bottom,
    left, right, its height and width there, and the move (du, dv) that takes its pixels
    back to the frame's; and the packed image's height and width."""
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
    return geo, height, x


@_jit
def pack_rois(mask, rois, pad):
    """The rectangles ``rois`` (v0, v1, u0, u1) of ``mask`` laid side by side in one image
    (``Segmenter._contours_holes``), each padded by ``pad`` pixels of its own mirror image
    (BORDER_REFLECT_101) on the sides where it meets the image's edge. Returns the image
    and ``roi_geometry``'s table."""
    h, w = mask.shape
    n = len(rois)
    geo, height, x = roi_geometry(rois, h, w, pad)
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
