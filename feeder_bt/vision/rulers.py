"""Rulers: gauges laid on a blob's outline from its centroid, in belt mm (the thesis's
"generalized linear and circular rulers", section 8.2.1.6). A recipe names them
(``vision.rulers``) and its classes range over them (``rulers: {NAME: [lo, hi]}``).

Both work on the outer contour mapped through the calibration, so they read the part as
the robot sees it (lens and tilt included) and need no pixels beyond the contour's:

- a *line* through the centroid at an angle to the blob's long axis: the distance between
  the outline's outermost crossings along it (a caliper: a width where the rectangle's
  sides say nothing, as across a part's waist);
- a *circle* about the centroid: how many separate arcs of it lie on the part (its
  crossings with the outline, in pairs): a sprocket's teeth, a connector's pins.

The contour runs through the centres of the blob's edge pixels, half a pixel inside the
edge, so a line's length gets a pixel added (as the perimeter does).
"""

from __future__ import annotations

import math

import cv2
import numpy as np

from feeder_bt.core.model import Ruler


def line_mm(outline: np.ndarray, centre: tuple[float, float], angle_deg: float) -> float:
    """The distance between the outermost crossings of ``outline`` (a closed ring, mm)
    with the line through ``centre`` at ``angle_deg``; 0 if it misses."""
    a = math.radians(angle_deg)
    ux, uy = math.cos(a), math.sin(a)
    d = outline - np.asarray(centre, dtype=float)
    side = ux * d[:, 1] - uy * d[:, 0]             # signed distance from the line
    along = ux * d[:, 0] + uy * d[:, 1]
    s0, s1 = side, np.roll(side, -1)
    cross = (s0 <= 0) != (s1 <= 0)
    if not cross.any():
        return 0.0
    f = s0[cross] / (s0[cross] - s1[cross])        # where along each crossed edge
    t = along[cross] + f * (np.roll(along, -1)[cross] - along[cross])
    return float(t.max() - t.min())


def circle_arcs(outline: np.ndarray, centre: tuple[float, float], radius_mm: float,
                band_mm: float = 0.0) -> float:
    """How many separate arcs of the circle of ``radius_mm`` about ``centre`` lie inside
    ``outline`` (a closed ring, mm). The outline counts as crossing only from inside
    ``radius_mm - band_mm`` to outside ``radius_mm + band_mm`` or back: a pixel staircase
    that wavers about the circle is one crossing, not several."""
    r = np.hypot(outline[:, 0] - centre[0], outline[:, 1] - centre[1])
    clear = np.abs(r - radius_mm) > band_mm
    out = (r > radius_mm)[clear]                   # the points clearly on either side
    crossings = int(np.count_nonzero(out != np.roll(out, -1))) if out.size else 0
    if crossings:
        return float(crossings // 2)
    probe = (centre[0] + radius_mm, centre[1])     # no crossing: all of it or none
    ring = outline.astype(np.float32).reshape(-1, 1, 2)
    return 1.0 if cv2.pointPolygonTest(ring, probe, False) >= 0 else 0.0


def measure(ruler: Ruler, outline: np.ndarray, centre: tuple[float, float],
            long_axis_deg: float, px_mm: float) -> float:
    """The ruler's reading on a blob (``long_axis_deg``: its principal axis, belt frame;
    ``px_mm``: a pixel's size, the contour's half-pixel inset on each side)."""
    if ruler.circle_mm is not None:
        return circle_arcs(outline, centre, ruler.circle_mm, band_mm=0.5 * px_mm)
    assert ruler.line_deg is not None
    length = line_mm(outline, centre, long_axis_deg + ruler.line_deg)
    return length + px_mm if length > 0 else 0.0
