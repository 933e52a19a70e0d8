"""Drawing what the locator made of a frame: the parts (class and pose; x, y and angle in
the belt frame; an arrow along the angle), the rejected blobs with each one's reason, and
every blob's outline. One drawing for `feeder locate --annotate` and the dashboard's
camera view, so what the operator sees is what a recipe's author checked."""

from __future__ import annotations

import math
from typing import Any

import cv2
import numpy as np

from feeder_bt.vision.pixels import Calibration
from feeder_bt.vision.segment import to_grey

ARROW_MM = 25.0                 # the angle arrow's length in the belt frame
PART = (0, 200, 0)              # BGR: located parts
REJECT = (0, 0, 230)            # rejected blobs
CONTOUR = (255, 160, 0)         # every blob's outline


def draw(image: np.ndarray, result: Any, calibration: Calibration | None
         ) -> tuple[np.ndarray, list[dict[str, Any]], list[dict[str, Any]]]:
    """A BGR copy of ``image`` with ``result`` drawn on it, and the parts and rejected
    blobs drawn, as plain data (rounded as labelled)."""
    out = cv2.cvtColor(to_grey(image), cv2.COLOR_GRAY2BGR)
    contours = getattr(result, "contours", None)
    if contours:
        cv2.drawContours(out, contours, -1, CONTOUR, 1, cv2.LINE_AA)
    parts: list[dict[str, Any]] = []
    for det in result.parts:
        c = (int(round(det.u_px)), int(round(det.v_px)))
        cv2.circle(out, c, 3, PART, -1, cv2.LINE_AA)
        if calibration is not None:
            a = math.radians(det.angle_deg)
            tip = calibration.mm_to_px(np.array([[det.x_mm + ARROW_MM * math.cos(a),
                                                  det.y_mm + ARROW_MM * math.sin(a)]]))[0]
            cv2.arrowedLine(out, c, (int(round(tip[0])), int(round(tip[1]))), PART, 1,
                            cv2.LINE_AA, tipLength=0.25)
        d = {"part": det.part, "pose": det.pose, "pickable": bool(det.pickable),
             "x_mm": round(det.x_mm, 1), "y_mm": round(det.y_mm, 1),
             "angle_deg": round(det.angle_deg, 1),
             "u_px": round(det.u_px, 1), "v_px": round(det.v_px, 1)}
        name = f"{det.part}/{det.pose}" + ("" if det.pickable else " (no pick)")
        _tag(out, [name, f"x {d['x_mm']:g} y {d['y_mm']:g} a {d['angle_deg']:g}"], c,
             _radius_px(det, calibration), (0, 120, 0))
        parts.append(d)
    rejected: list[dict[str, Any]] = []
    for det in result.rejected:
        c = (int(round(det.u_px)), int(round(det.v_px)))
        cv2.drawMarker(out, c, REJECT, cv2.MARKER_TILTED_CROSS, 10, 2)
        _tag(out, [det.reason], c, 6, REJECT)
        rejected.append({"reason": det.reason, "x_mm": round(det.x_mm, 1),
                         "y_mm": round(det.y_mm, 1), "u_px": round(det.u_px, 1),
                         "v_px": round(det.v_px, 1)})
    return out, parts, rejected


def _radius_px(det: Any, calibration: Calibration | None) -> int:
    """About the blob's radius in pixels, to put its label beside it, not on it."""
    area = det.features.get("area_mm2") if isinstance(det.features, dict) else None
    scale = calibration.mm_per_px if calibration is not None else 1.0
    return int(math.sqrt(area / math.pi) / scale) if area else 8


def _tag(out: np.ndarray, lines: list[str], at: tuple[int, int], r: int,
         colour: tuple[int, int, int]) -> None:
    """Lines of text on a pale box right of ``at`` (left of it near the right edge),
    kept inside the image, so that they read on dark parts and bright belt alike."""
    font, scale = cv2.FONT_HERSHEY_SIMPLEX, 0.38
    sizes = [cv2.getTextSize(t, font, scale, 1)[0] for t in lines]
    w = max(s[0] for s in sizes) + 4
    lh = max(s[1] for s in sizes) + 5
    h = lh * len(lines) + 2
    x = at[0] + r + 3
    if x + w > out.shape[1]:
        x = at[0] - r - 3 - w
    x = min(max(x, 0), max(out.shape[1] - w, 0))
    y = min(max(at[1] - h // 2, 0), max(out.shape[0] - h, 0))
    box = out[y:y + h, x:x + w]
    box[:] = (box.astype(np.uint16) + 3 * 255) // 4          # a pale box, the belt showing
    for i, t in enumerate(lines):
        cv2.putText(out, t, (x + 2, y + lh * (i + 1) - 2), font, scale, colour, 1,
                    cv2.LINE_AA)
