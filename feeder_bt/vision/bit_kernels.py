"""Compiled kernels (numba; see ``vision.kernels``, which imports them): the packing of a
mask's rectangles of foreground (``contour_kernels.pack_rois``) with the opening and
closing done on the packed image one bit a pixel, in one call (``packed_morph``).

OpenCV's ``morphologyEx`` reads and writes a byte a pixel, twice per operation (erode,
dilate), with a call and an image of its own each; here 64 pixels are one word and an
operation is a few shifts and ANDs (ORs) of whole words: pixel for pixel OpenCV's result
(``tests/vision/test_locator.py::test_contours_on_bands_equal_the_whole_frame`` compares the
contours found with OpenCV's on the whole frame, random masks, kernels 3 to 9 pixels).
"""

from __future__ import annotations

import numpy as np

from feeder_bt.vision.contour_kernels import (
    _reflect,
    foreground_rois,
    golden_threshold,
    roi_geometry,
)
from feeder_bt.vision.kernel_jit import _jit

_ONES = np.uint64(0xFFFFFFFFFFFFFFFF)
_HIGH = np.uint64(0x8080808080808080)
_GATHER = np.uint64(0x0002040810204081)     # each byte's high bit -> the top byte, in order


@_jit(inline="always")
def _eight(lo, hi, s):
    """Eight pixels of a mask row given 8 pixels a word (0/255 bytes), the words ``lo``,
    ``hi`` holding them from byte s // 8 of ``lo`` on, as 8 bits, the first the lowest.
    (Scalars only: an array passed to a compiled function is counted in and out.)"""
    x = lo >> s
    if s:
        x |= hi << (np.uint64(64) - s)
    return ((x & _HIGH) * _GATHER) >> np.uint64(56)


@_jit
def _pack_bits(words, rois, geo, height, width):
    """``pack_rois``' image one bit a pixel: (height, words of 64) uint64, bit x of a row
    its pixel x (0 past ``width``). The mirrored columns a pixel at a time, the rest
    eight at a time."""
    nw = words.shape[1]
    bits = np.zeros((height, (width + 63) // 64 + 1), np.uint64)
    one = np.uint64(1)
    for i in range(len(rois)):
        v0, v1, u0, u1 = rois[i, 0], rois[i, 1], rois[i, 2], rois[i, 3]
        x0, top, left, sh, sw = geo[i, 0], geo[i, 1], geo[i, 3], geo[i, 5], geo[i, 6]
        inner = u1 - u0
        for r in range(sh):
            src = np.uintp(v0 + _reflect(r - top, v1 - v0))
            out = np.uintp(r)
            for j in range(sw - inner):                 # the mirrored pixels
                c = j if j < left else j + inner
                u = u0 + _reflect(c - left, inner)
                if words[src, np.uintp(u >> 3)] >> np.uint64(8 * (u & 7)) & one:
                    x = x0 + c
                    bits[out, np.uintp(x >> 6)] |= one << np.uint64(x & 63)
            for c in range(0, inner, 8):
                u = u0 + c
                k = np.uintp(u >> 3)
                hi = words[src, k + np.uintp(1)] if k + 1 < nw else np.uint64(0)
                byte = _eight(words[src, k], hi, np.uint64(8 * (u & 7)))
                n = min(8, inner - c)
                byte &= (one << np.uint64(n)) - one
                x = x0 + left + c
                q, s = np.uintp(x >> 6), np.uint64(x & 63)
                bits[out, q] |= byte << s
                if s > np.uint64(64 - n):
                    bits[out, q + np.uintp(1)] |= byte >> (np.uint64(64) - s)
    return bits


@_jit
def _morph_pass(src, dst, width, dys, dxs, dilate):
    """One erosion (AND) or dilation (OR) of the bit image ``src`` into ``dst`` by the
    kernel points (dy, dx): pixel (x, y) from src's (x + dx, y + dy), as ``cv2.erode`` and
    ``cv2.dilate`` read them. Outside the image nothing constrains: an erosion reads ones
    there, a dilation zeros (OpenCV's default border)."""
    h, nw = src.shape
    last = (width - 1) >> 6                       # the last word with pixels
    fill = np.uint64(0) if dilate else _ONES
    # past the last pixel the image reads ``fill``
    tail = _ONES << np.uint64(width & 63) if width & 63 else np.uint64(0)
    for y in range(h):
        row = src[np.uintp(y)]
        row[np.uintp(last)] = (row[np.uintp(last)] & ~tail) | (fill & tail)
        for k in range(last + 1, nw):
            row[np.uintp(k)] = fill
    for y in range(h):
        out = dst[np.uintp(y)]
        for k in range(nw):
            out[np.uintp(k)] = fill
        for p in range(len(dys)):
            yy = y + dys[p]
            if yy < 0 or yy >= h:
                continue
            row = src[np.uintp(yy)]
            dx = dxs[p]
            if dx == 0:
                for k in range(last + 1):
                    if dilate:
                        out[np.uintp(k)] |= row[np.uintp(k)]
                    else:
                        out[np.uintp(k)] &= row[np.uintp(k)]
            elif dx > 0:                              # out bit x = row bit x + dx
                s = np.uint64(dx)
                for k in range(last + 1):
                    x = (row[np.uintp(k)] >> s) | (row[np.uintp(k + 1)] << (np.uint64(64) - s))
                    if dilate:
                        out[np.uintp(k)] |= x
                    else:
                        out[np.uintp(k)] &= x
            else:
                s = np.uint64(-dx)
                for k in range(last + 1):
                    before = row[np.uintp(k - 1)] if k else fill
                    x = (row[np.uintp(k)] << s) | (before >> (np.uint64(64) - s))
                    if dilate:
                        out[np.uintp(k)] |= x
                    else:
                        out[np.uintp(k)] &= x


_SPREAD = np.zeros(256, np.uint64)                  # 8 bits -> 8 bytes of 0 / 255
for _b in range(256):
    for _j in range(8):
        if _b >> _j & 1:
            _SPREAD[_b] |= np.uint64(255) << np.uint64(8 * _j)


@_jit
def packed_morph(words, h, w, margin, open_dy, open_dx, close_dy, close_dx):
    """``foreground_rois`` of an h x w mask (given 8 pixels a word), their ``pack_rois``
    image with mirrors ``margin`` wide, opened and closed by the kernel points given
    (dy, dx; none: no such operation), the mirrors cleared:
    (rectangles, the image as 0/255 bytes in words of 8, geometry, its width in pixels).
    Without kernels, the packing alone (``margin`` 1)."""
    rois = foreground_rois(words, h, w, margin)
    geo, height, width = roi_geometry(rois, h, w, margin)
    bits = _pack_bits(words, rois, geo, height, width)
    spare = np.empty_like(bits)
    if len(open_dy):
        _morph_pass(bits, spare, width, open_dy, open_dx, False)
        _morph_pass(spare, bits, width, open_dy, open_dx, True)
    if len(close_dy):
        _morph_pass(bits, spare, width, close_dy, close_dx, True)
        _morph_pass(spare, bits, width, close_dy, close_dx, False)
    for i in range(len(geo)):                       # the mirrors cleared
        x0, top, bottom, left, right, sh, sw = (geo[i, 0], geo[i, 1], geo[i, 2], geo[i, 3],
                                                 geo[i, 4], geo[i, 5], geo[i, 6])
        if top + bottom + left + right == 0:
            continue
        for r in range(height):
            whole = r < top or sh - bottom <= r < sh
            for a, b in ((x0, x0 + sw if whole else x0 + left),
                         (x0 + sw if whole else x0 + sw - right, x0 + sw)):
                for x in range(a, b):
                    bits[np.uintp(r), np.uintp(x >> 6)] &= ~(np.uint64(1) << np.uint64(x & 63))
    nw = (width + 63) // 64
    out = np.empty((height, nw * 8), np.uint64)
    for r in range(height):
        for k in range(nw):
            word = bits[r, k]
            for j in range(8):
                out[r, k * 8 + j] = _SPREAD[(word >> np.uint64(8 * j)) & np.uint64(255)]
    return rois, out, geo, width


@_jit
def golden_morph(img, golden, golden_small, step, otsu, value, light, padded, margin,
                 open_dy, open_dx, close_dy, close_dx):
    """A frame against its golden image, to ``packed_morph``'s result, in one call: the
    level and the mask (``golden_threshold``, into ``padded``: this thread's scratch mask,
    rows of whole words, zeros past the last pixel), its rectangles, packing, opening and
    closing. Returns (level, rectangles, image, geometry, width), as ``packed_morph``.

    One call where there were three (Otsu's level, OpenCV's compare, the packing), each
    with its way in from Python, which costs several times more after other work has
    emptied the caches (docs/performance.md)."""
    level = golden_threshold(img, golden, golden_small, step, otsu, value, light, padded)
    h, w = img.shape
    rois, out, geo, width = packed_morph(padded.view(np.uint64), h, w, margin,
                                         open_dy, open_dx, close_dy, close_dx)
    return level, rois, out, geo, width
