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

ARROW_REACH = 1.15              # the angle arrow reaches this far past the part's farthest point
LABEL_RINGS = 3                 # a label is tried this many label heights out at most
PART = (0, 200, 0)              # BGR: located parts
REJECT = (0, 0, 230)            # rejected blobs
CONTOUR = (255, 160, 0)         # every blob's outline


def draw(image: np.ndarray, result: Any, calibration: Calibration | None
         ) -> tuple[np.ndarray, list[dict[str, Any]], list[dict[str, Any]]]:
    """A BGR copy of ``image`` with ``result`` drawn on it, and the parts and rejected
    blobs drawn, as plain data (rounded as labelled; ``label_px``: the label's box).

    The angle arrow reaches just past the part's farthest point from its centre and
    is drawn only where the angle means something: not for a class that reads none, nor
    for a part any angle of which is right, a disc (``LocateResult.angled``; every part
    when the result does not say). Labels are put where they cover no other label
    (right, left, above, below the part, then farther out); where none is free, only the
    name is written, or nothing (``label_px`` None)."""
    out = cv2.cvtColor(to_grey(image), cv2.COLOR_GRAY2BGR)
    contours = getattr(result, "contours", None)
    if contours:
        cv2.drawContours(out, contours, -1, CONTOUR, 1, cv2.LINE_AA)
    angled = getattr(result, "angled", None)
    far = {id(b.det): b for b in getattr(result, "blobs", ())}     # each part's outline
    # no label covers a part's or a reject's mark
    taken = [(int(round(d.u_px)) - 5, int(round(d.v_px)) - 5, 11, 11)
             for d in (*result.parts, *result.rejected)]
    parts: list[dict[str, Any]] = []
    for det in result.parts:
        c = (int(round(det.u_px)), int(round(det.v_px)))
        cv2.circle(out, c, 3, PART, -1, cv2.LINE_AA)
        b = far.get(id(det))            # the part's farthest point: arrow and label past it
        r = int(np.hypot(*(b.contour.reshape(-1, 2) - c).T).max()) if b is not None \
            else _radius_px(det, calibration)
        if calibration is not None and (angled is None or (det.part, det.pose) in angled):
            a = math.radians(det.angle_deg)
            reach = ARROW_REACH * r * calibration.mm_per_px
            tip = calibration.mm_to_px(np.array([[det.x_mm + reach * math.cos(a),
                                                  det.y_mm + reach * math.sin(a)]]))[0]
            cv2.arrowedLine(out, c, (int(round(tip[0])), int(round(tip[1]))), PART, 1,
                            cv2.LINE_AA, tipLength=0.25)
        d = {"part": det.part, "pose": det.pose, "pickable": bool(det.pickable),
             "x_mm": round(det.x_mm, 1), "y_mm": round(det.y_mm, 1),
             "angle_deg": round(det.angle_deg, 1),
             "u_px": round(det.u_px, 1), "v_px": round(det.v_px, 1)}
        name = f"{det.part}/{det.pose}" + ("" if det.pickable else " (no pick)")
        d["label_px"] = _tag(out, [name, f"x {d['x_mm']:g} y {d['y_mm']:g} a {d['angle_deg']:g}"],
                             c, r, (0, 120, 0), taken)
        parts.append(d)
    rejected: list[dict[str, Any]] = []
    for det in result.rejected:
        c = (int(round(det.u_px)), int(round(det.v_px)))
        cv2.drawMarker(out, c, REJECT, cv2.MARKER_TILTED_CROSS, 10, 2)
        box = _tag(out, [det.reason], c, 6, REJECT, taken)
        rejected.append({"reason": det.reason, "x_mm": round(det.x_mm, 1),
                         "y_mm": round(det.y_mm, 1), "u_px": round(det.u_px, 1),
                         "v_px": round(det.v_px, 1), "label_px": box})
    return out, parts, rejected


def _radius_px(det: Any, calibration: Calibration | None) -> int:
    """About the blob's radius in pixels, to put its label beside it, not on it."""
    area = det.features.get("area_mm2") if isinstance(det.features, dict) else None
    scale = calibration.mm_per_px if calibration is not None else 1.0
    return int(math.sqrt(area / math.pi) / scale) if area else 8


def _overlap(a: tuple[int, int, int, int], b: tuple[int, int, int, int]) -> int:
    """Pixels two boxes (x, y, w, h) share."""
    w = min(a[0] + a[2], b[0] + b[2]) - max(a[0], b[0])
    h = min(a[1] + a[3], b[1] + b[3]) - max(a[1], b[1])
    return max(w, 0) * max(h, 0)


def _tag(out: np.ndarray, lines: list[str], at: tuple[int, int], r: int,
         colour: tuple[int, int, int], taken: list[tuple[int, int, int, int]]
         ) -> list[int] | None:
    """Lines of text on a pale box beside ``at`` (``r`` px from it), kept inside the
    image, so that they read on dark parts and bright belt alike: the nearest place
    (right, left, above, below, then as much farther out, up to ``LABEL_RINGS`` times)
    whose box covers none of ``taken``; else the first line alone, placed so; else none
    (a crowd of labels covering each other reads as none). The box drawn is added to
    ``taken`` and returned."""
    font, scale = cv2.FONT_HERSHEY_SIMPLEX, 0.38
    ih, iw = out.shape[:2]

    def free(texts: list[str]) -> tuple[int, int, int, int] | None:
        sizes = [cv2.getTextSize(t, font, scale, 1)[0] for t in texts]
        w = max(s[0] for s in sizes) + 4
        h = (max(s[1] for s in sizes) + 5) * len(texts) + 2
        for ring in range(LABEL_RINGS):
            g = r + 3 + ring * h
            for x, y in ((at[0] + g, at[1] - h // 2), (at[0] - g - w, at[1] - h // 2),
                         (at[0] - w // 2, at[1] - g - h), (at[0] - w // 2, at[1] + g)):
                box = (min(max(x, 0), max(iw - w, 0)), min(max(y, 0), max(ih - h, 0)), w, h)
                if not any(_overlap(box, t) for t in taken):
                    return box
        return None

    box = free(lines)
    if box is None:
        lines = lines[:1]
        box = free(lines)
        if box is None:
            return None
    x, y, w, h = box
    lh = (h - 2) // len(lines)
    region = out[y:y + h, x:x + w]
    region[:] = (region.astype(np.uint16) + 3 * 255) // 4    # a pale box, the belt showing
    for i, t in enumerate(lines):
        cv2.putText(out, t, (x + 2, y + lh * (i + 1) - 2), font, scale, colour, 1,
                    cv2.LINE_AA)
    taken.append(box)
    return list(box)
