"""Example leaf classes: what a new part needs when YAML alone cannot say it.

``TriangleLocator`` is the recipe's locator plus one step for triangular parts. A scalene
triangle (three different sides) looks different from each face and has one true angle,
but the YAML orientations cannot find either: ``principal_axis`` gives an angle modulo
180° and no face; ``cut_corner`` needs a square with one corner cut. Used by
``examples/gussets.yaml`` as ``vision: {leaf: examples.leaves:TriangleLocator}``; see
docs/adding-a-part.md.
"""

from __future__ import annotations

import math

import cv2
import numpy as np

from feeder_bt.api import Detection, LocateResult, Locator, pose_outline


class TriangleLocator(Locator):
    """Orients triangular parts and tells their faces apart from the silhouette.

    The recipe classifies as usual; for parts whose outline is a scalene triangle, the blob's
    minimum enclosing triangle (in mm, after the calibration, so handedness is the belt's)
    gives the vertices. Labelled by the length of the side opposite each, they fix the
    angle, and the sign of their winding fixes the face. The class of the part with the
    matching ``mirrored`` is chosen; if the recipe has none, the blob is rejected.
    """

    def __init__(self, recipe, parts, calibration) -> None:
        super().__init__(recipe, parts, calibration)
        self._models: dict[str, np.ndarray] = {}
        for cls in recipe.classes:
            outline = pose_outline(parts[cls.part], _plain_pose(parts[cls.part]))
            if len(outline) == 3 and cls.part not in self._models:
                self._models[cls.part] = _labelled(outline)

    def locate(self, image: np.ndarray, all_features: bool = False) -> LocateResult:
        result = super().locate(image, all_features)
        keep: list[Detection] = []
        for det in result.parts:
            model = self._models.get(det.part or "")
            if model is not None and not self._orient(det, model, result.contours):
                result.rejected.append(det)
            else:
                keep.append(det)
        result.parts = keep
        return result

    def _orient(self, det: Detection, model: np.ndarray, contours: list[np.ndarray]) -> bool:
        """Set the angle, face and class of a triangle; False (with a reason) if impossible."""
        contour = next((c for c in contours
                        if cv2.pointPolygonTest(c, (det.u_px, det.v_px), False) >= 0), None)
        if contour is None:
            det.reason = "no outline"
            return False
        xy = self.calibration.px_to_mm(contour.reshape(-1, 2)).astype(np.float32)
        _, tri = cv2.minEnclosingTriangle(cv2.convexHull(xy))
        seen = _labelled(tri.reshape(3, 2).astype(float))
        mirrored = _winding(seen) != _winding(model)
        ref = model * np.array([1.0, -1.0]) if mirrored else model   # the face seen
        a_seen = _direction(seen[2] - seen[0])
        a_model = _direction(ref[2] - ref[0])
        det.angle_deg = math.degrees(math.remainder(a_seen - a_model, 2 * math.pi))
        det.features["mirrored"] = 1.0 if mirrored else 0.0
        cls = next((c for c in self.recipe.classes
                    if c.part == det.part and c.mirrored in (mirrored, None)), None)
        if cls is None:
            det.reason = "no class (face)"
            return False
        det.pose, det.pickable = cls.pose, cls.pickable
        return True


def _plain_pose(part) -> str:
    """The pose showing the part's own outline (not mirrored, no other silhouette)."""
    return next((n for n, p in part.poses.items() if not p.mirror and p.silhouette is None),
                next(iter(part.poses)))


def _labelled(tri: np.ndarray) -> np.ndarray:
    """Vertices ordered by the length of the opposite side, shortest first."""
    opposite = [np.hypot(*(tri[(i + 1) % 3] - tri[(i + 2) % 3])) for i in range(3)]
    return tri[np.argsort(opposite)]


def _winding(tri: np.ndarray) -> bool:
    (ax, ay), (bx, by) = tri[1] - tri[0], tri[2] - tri[0]
    return ax * by - ay * bx > 0


def _direction(v: np.ndarray) -> float:
    return math.atan2(v[1], v[0])
