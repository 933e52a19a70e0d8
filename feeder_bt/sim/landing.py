"""Parts on the horizontal belt: where they land and come to rest, where each is at any
time, and which touch.

A landing part may come down against or on the one before it (parts leave the hopper in
clumps), then slides and turns a little while it settles (``imperfect.py``); two parts
closer than ``TOUCH_GAP_MM`` touch, and neither is then singulated (the robot's grip is
refused). Judged against the parts' true outlines, never shown to the locator.

``Landing`` is a part of ``World`` (``world.py``), kept here by concept.
"""

from __future__ import annotations

import math
from collections import Counter

import cv2
import numpy as np

from feeder_bt.core.geometry import (
    circumradius,
    is_convex,
    near,
    outer,
    place_outline,
    polygon_area,
    pose_outline,
    wrap_deg,
)
from feeder_bt.core.model import Scenario
from feeder_bt.sim.accounting import SimPart
from feeder_bt.sim.axis import Axis
from feeder_bt.sim.imperfect import Imperfections

LAND_X_MM = (15.0, 45.0)        # where parts land on the horizontal belt, off the ramp
EDGE_MARGIN_MM = 28.0           # side rails keep parts this far from the belt edges
TOUCH_GAP_MM = 1.0              # closer than this, two parts count as touching


class Landing:
    """Rest poses, positions and touching of the parts on the belt (a part of ``World``)."""

    # what it uses of the world (``World.__init__`` makes them)
    scenario: Scenario
    parts: dict[int, SimPart]
    on_horizontal: dict[int, SimPart]
    horizontal: Axis
    h_width: float
    imperfect: Imperfections
    counts: Counter[str]
    _last_landed: int | None
    _outlines: dict[tuple[str, str], np.ndarray]
    _areas: dict[tuple[str, str], float]
    _radii: dict[tuple[str, str], float]

    def outline(self, ptype: str, pose: str) -> np.ndarray:
        """A part's outline in a pose (part frame; with holes, NaN rows part its rings: see
        ``feeder_bt.core.geometry``), made once per part type and pose."""
        key = (ptype, pose)
        if key not in self._outlines:
            self._outlines[key] = pose_outline(self.scenario.parts[ptype], pose)
        return self._outlines[key]

    def radius(self, ptype: str, pose: str) -> float:
        """``circumradius`` of ``outline(ptype, pose)``, made once (every landing asks)."""
        key = (ptype, pose)
        r = self._radii.get(key)
        if r is None:
            r = self._radii[key] = circumradius(self.outline(ptype, pose))
        return r

    def part_xy(self, part: SimPart, t: float) -> tuple[float, float]:
        if t < part.settle_end:                 # still sliding to its rest pose
            left = (1.0 - (t - part.settle_t0) / (part.settle_end - part.settle_t0)) ** 2
            return (part.x0 + self.horizontal.pos(t) - part.slide[0] * left,
                    part.y - part.slide[1] * left)
        return part.x0 + self.horizontal.pos(t), part.y

    def _imperfect_landing(self, part: SimPart, t: float, dropped: bool) -> None:
        """A landing part may come down against or on the one before it (parts leave the
        hopper in clumps), then slides and turns a little while it settles; its touching
        is judged at its rest pose. Nothing happens on an ideal cell."""
        imp = self.imperfect
        if imp.ideal:
            return
        prev = self.on_horizontal.get(self._last_landed) if not dropped else None
        if not dropped:
            self._last_landed = part.id
        if prev is not None and (c := imp.clump(self.zone_cover(t))) is not None:
            ang, frac = c
            dist = frac * (part.radius + prev.radius)
            part.x0 = prev.x0 + dist * math.cos(ang)
            part.y = prev.y + dist * math.sin(ang)
            self.counts["landed_clumped"] += 1
        dx, dy, turn, settle = imp.landing(dropped)
        y_rest = min(max(part.y + dy, EDGE_MARGIN_MM), self.h_width - EDGE_MARGIN_MM)
        part.slide = (dx, y_rest - part.y)
        part.x0 += dx
        part.y = y_rest
        part.angle = wrap_deg(part.angle + turn)
        part.settle_t0, part.settle_end = t, (t + settle if settle > 0 else -math.inf)

    def zone_cover(self, t: float) -> float:
        """The fraction of the landing zone (the belt's first ``sim.clump_zone_mm``, its
        full width) that the parts on the belt cover at ``t``: how loaded the belt is where
        parts land (a part overlapping the zone's end counts whole)."""
        zone = self.imperfect.spec.clump_zone_mm
        belt = self.horizontal.pos(t)
        area = 0.0
        for p in self.on_horizontal.values():
            if p.x0 + belt - p.radius < zone:
                area += self._area(p)
        return area / (zone * self.h_width)

    def _area(self, part: SimPart) -> float:
        key = (part.type, part.pose)
        a = self._areas.get(key)
        if a is None:
            a = self._areas[key] = polygon_area(self.outline(part.type, part.pose))
        return a

    def _settle(self, part: SimPart, t: float) -> None:
        """A part comes to rest on the horizontal belt (landing, or dropped by the robot):
        which parts does it touch? It lands at the belt's speed (slip.py)."""
        part.slip_v = 0.0
        belt = self.horizontal.pos(t)
        ax, ay = part.x0 + belt, part.y             # part_xy(part, t)
        for other in self.on_horizontal.values():
            # _touch's own first test, here without a call per part on the belt
            if other is part or math.hypot(ax - (other.x0 + belt), ay - other.y) > \
                    part.radius + other.radius + TOUCH_GAP_MM:
                continue
            if self._touch(part, other, t):
                part.touching.add(other.id)
                other.touching.add(part.id)

    def _touch(self, a: SimPart, b: SimPart, t: float) -> bool:
        """Whether two parts on the belt are closer than ``TOUCH_GAP_MM``. Convex outlines:
        their grown polygons intersect (exact, fast). Otherwise (concave outlines; holes do
        not matter, only the outer rings can meet): ``geometry.near`` on a fine raster."""
        ax, ay = self.part_xy(a, t)
        bx, by = self.part_xy(b, t)
        if math.hypot(ax - bx, ay - by) > a.radius + b.radius + TOUCH_GAP_MM:
            return False
        oa, ob = outer(a.outline), outer(b.outline)
        if is_convex(oa) and is_convex(ob):
            pa = _grown(place_outline(oa, ax, ay, a.angle), (ax, ay), TOUCH_GAP_MM / 2)
            pb = _grown(place_outline(ob, bx, by, b.angle), (bx, by), TOUCH_GAP_MM / 2)
            area, _ = cv2.intersectConvexConvex(pa.astype(np.float32), pb.astype(np.float32))
            return area > 0.0
        return near(place_outline(oa, ax, ay, a.angle), place_outline(ob, bx, by, b.angle),
                    TOUCH_GAP_MM)

    def _untouch(self, part: SimPart) -> None:
        for oid in part.touching:
            self.parts[oid].touching.discard(part.id)
        part.touching.clear()


def _grown(poly: np.ndarray, centre: tuple[float, float], by: float) -> np.ndarray:
    c = np.asarray(centre)
    v = poly - c
    n = np.linalg.norm(v, axis=1, keepdims=True)
    return c + v * (1.0 + by / np.maximum(n, 1e-9))
