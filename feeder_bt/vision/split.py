"""Splitting touching parts (``vision.split_touching``, off by default).

A blob that fits no class and is big enough to be two or more parts is cut by the
distance transform: the blob's own mask (its bounding box only), the distance of each
pixel to the background, one marker per peak of that distance (the cores above ``CORE``
of the highest), and each pixel given to its nearest core (the distance transform's
labels: a watershed of the distance to the cores, whose cut between two alike parts is
their bisector, through the neck). OpenCV's ``cv2.watershed`` floods by colour
difference, not by a relief, and cut two touching lenses 10:1 in trials. Each piece is then measured
and classified like any blob; a piece that fits no class stays rejected (with the whole
blob), so a clump that does not cut into whole parts is never offered. A piece's centroid
is the part's as far as the cut is straight: parts touching along a short neck (discs,
rounded parts) split well, parts lying on one another do not split into whole outlines
and fit no class.
"""

from __future__ import annotations

import cv2
import numpy as np

from feeder_bt.vision.blobs import Blob

CORE = 0.7                   # a marker: pixels farther than this of the maximum distance


def split_blob(b: Blob) -> list[tuple[np.ndarray, list[np.ndarray]]]:
    """The pieces of blob ``b``, each its outer contour and its holes' (whole-frame
    pixels); [] if it does not cut into two or more."""
    u, v, w, h = b.box
    pad = 2
    mask = np.zeros((h + 2 * pad, w + 2 * pad), np.uint8)
    cv2.drawContours(mask, [b.contour], -1, 255, thickness=cv2.FILLED,
                     offset=(pad - u, pad - v))
    # the distance over the filled outline (a washer's core is its middle, not its ring);
    # the pieces keep the holes
    dist = cv2.distanceTransform(mask, cv2.DIST_L2, 5)
    if b.holes:
        cv2.drawContours(mask, b.holes, -1, 0, thickness=cv2.FILLED, offset=(pad - u, pad - v))
        cv2.drawContours(mask, b.holes, -1, 255, thickness=1, offset=(pad - u, pad - v))
    peak = float(dist.max())
    if peak <= 1.0:
        return []
    cores = (dist > CORE * peak).astype(np.uint8)
    n, _ = cv2.connectedComponents(cores)
    if n < 3:                                    # the background and one core: one part
        return []
    # each pixel to its nearest core (labels 1..n-1 by component): between two cores the
    # cut is their bisector, which for parts alike is the line through the neck
    _, nearest = cv2.distanceTransformWithLabels(1 - cores, cv2.DIST_L2, 5,
                                                 labelType=cv2.DIST_LABEL_CCOMP)
    out: list[tuple[np.ndarray, list[np.ndarray]]] = []
    for k in range(1, int(nearest.max()) + 1):
        piece = ((nearest == k) & (mask > 0)).astype(np.uint8)
        cs, hier = cv2.findContours(piece, cv2.RETR_CCOMP, cv2.CHAIN_APPROX_NONE,
                                    offset=(u - pad, v - pad))
        outers = [i for i in range(len(cs)) if hier[0][i][3] == -1]
        if not outers:
            continue
        i = max(outers, key=lambda j: cv2.contourArea(cs[j]))
        out.append((cs[i], [cs[j] for j in range(len(cs)) if hier[0][j][3] == i]))
    return out if len(out) >= 2 else []
