"""Splitting touching parts (``vision.split_touching``, off by default).

A blob that fits no class and is big enough to be two or more parts is cut by the
distance transform: the blob's own mask (its bounding box only), the distance of each
pixel to the background, one marker per dome of that distance that stands at least
``h_px`` above the saddle to its neighbours (the h-maxima: ``h_px`` is a share of the
smallest part's own inscribed radius, ``Locator``), so that a small coin beside a big one
has its own marker (a marker above a share of the highest distance missed it). Each pixel
goes to the marker whose part it is nearest the edge of: the least distance to the marker
less the marker's own radius (its peak distance), whose cut between two touching discs of
any sizes is the line through the neck; for parts alike it is their bisector. OpenCV's
``cv2.watershed`` floods by colour difference, not by a relief, and cut two touching lenses
10:1 in trials. Each piece is then measured and classified like any blob; a piece that fits
no class stays rejected (with the whole blob), so a clump that does not cut into whole
parts is never offered. A piece's centroid is the part's as far as the cut is straight:
parts touching along a short neck (discs, rounded parts) split well, parts lying on one
another do not split into whole outlines and fit no class.
"""

from __future__ import annotations

import cv2
import numpy as np

from feeder_bt.core.geometry import outer
from feeder_bt.vision.blobs import Blob

CORE = 0.7                   # without ``h_px``: a marker is beyond this of the maximum distance
H_SHARE = 0.3                # ``h_px``: this share of the smallest part's inscribed radius


def inscribed_px(outline: np.ndarray, px_mm: float) -> float:
    """The radius (px at ``px_mm`` mm per pixel) of the largest disc inside an outline's
    outer ring (mm, part frame): how far its dome of the distance transform rises."""
    px = outer(outline) / px_mm
    lo = px.min(axis=0) - 2
    size = np.ceil(px.max(axis=0) - lo).astype(int) + 3
    mask = np.zeros((int(size[1]), int(size[0])), np.uint8)
    cv2.fillPoly(mask, [np.round(px - lo).astype(np.int32).reshape(-1, 1, 2)], 255)
    return float(cv2.distanceTransform(mask, cv2.DIST_L2, 5).max())


def _reconstruct(marker: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """Grey reconstruction by dilation of ``marker`` under ``mask`` (both float32)."""
    k = np.ones((3, 3), np.uint8)
    while True:
        nxt = np.minimum(cv2.dilate(marker, k), mask)
        if np.array_equal(nxt, marker):
            return nxt
        marker = nxt


def h_maxima(dist: np.ndarray, h: float) -> np.ndarray:
    """The tops of the domes of ``dist`` that stand at least ``h`` above every saddle to a
    higher one (uint8 mask): the regional maxima of its h-maxima transform."""
    tops = _reconstruct(np.maximum(dist - h, 0), dist)
    step = np.float32(0.01)
    return ((tops - _reconstruct(np.maximum(tops - step, 0), tops)) > step / 2).astype(np.uint8)


def split_blob(b: Blob, h_px: float | None = None, shape: tuple[int, int] | None = None
               ) -> list[tuple[np.ndarray, list[np.ndarray]]]:
    """The pieces of blob ``b``, each its outer contour and its holes' (whole-frame
    pixels); [] if it does not cut into two or more. ``h_px``: how far a part's dome of
    the distance stands above its saddles at least (None: markers beyond ``CORE`` of the
    highest distance, for parts of one size). ``shape``: the frame's (height, width); a
    blob on its edge is drawn on past it (its edge row repeated), so that a part cut by
    the edge still has a dome of its own and its piece, though it touches the edge, is
    cut off the whole part beside it."""
    u, v, w, h = b.box
    pad = 2
    out_ = max(w, h) + pad                       # how far a blob is drawn on past the edge
    height, width = shape if shape is not None else (-1, -1)
    top, left = (out_ if v <= 0 else pad), (out_ if u <= 0 else pad)
    bottom = out_ if shape is not None and v + h >= height else pad
    right = out_ if shape is not None and u + w >= width else pad
    mask = np.zeros((h + top + bottom, w + left + right), np.uint8)
    off = (left - u, top - v)
    cv2.drawContours(mask, [b.contour], -1, 255, thickness=cv2.FILLED, offset=off)
    inside = mask.copy()
    if top > pad:
        mask[:top] = mask[top]
    if bottom > pad:
        mask[top + h:] = mask[top + h - 1]
    if left > pad:
        mask[:, :left] = mask[:, left:left + 1]
    if right > pad:
        mask[:, left + w:] = mask[:, left + w - 1:left + w]
    # the distance over the filled outline (a washer's core is its middle, not its ring);
    # the pieces keep the holes
    dist = cv2.distanceTransform(mask, cv2.DIST_L2, 5)
    if b.holes:
        cv2.drawContours(inside, b.holes, -1, 0, thickness=cv2.FILLED, offset=off)
        cv2.drawContours(inside, b.holes, -1, 255, thickness=1, offset=off)
    peak = float(dist.max())
    if peak <= 1.0:
        return []
    cores = (dist > CORE * peak).astype(np.uint8) if h_px is None else h_maxima(dist, h_px)
    n, labels = cv2.connectedComponents(cores)
    if n < 3:                                    # the background and one core: one part
        return []
    # each pixel to the core whose part's edge it is nearest: the distance to the core
    # less the core's radius (for parts alike, the bisector through the neck)
    reach = np.stack([cv2.distanceTransform((labels != k).astype(np.uint8), cv2.DIST_L2, 5)
                      - dist[labels == k].max() for k in range(1, n)])
    nearest = reach.argmin(axis=0) + 1
    out: list[tuple[np.ndarray, list[np.ndarray]]] = []
    for k in range(1, n):
        piece = ((nearest == k) & (inside > 0)).astype(np.uint8)
        cs, hier = cv2.findContours(piece, cv2.RETR_CCOMP, cv2.CHAIN_APPROX_NONE,
                                    offset=(-off[0], -off[1]))
        outers = [i for i in range(len(cs)) if hier[0][i][3] == -1]
        if not outers:
            continue
        i = max(outers, key=lambda j: cv2.contourArea(cs[j]))
        out.append((cs[i], [cs[j] for j in range(len(cs)) if hier[0][j][3] == i]))
    return out if len(out) >= 2 else []
