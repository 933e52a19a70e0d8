"""The robot base's pose in the cell frame from touch points (FRAME_SPEC).

The person jogs the tool onto marks at known cell-frame points; the robot reports each in
its own world frame (``HERE``). A rigid 2-D fit ``p_cell = Rot(a) p_robot + b`` by least
squares (the orthogonal Procrustes solution, no scale: an arm's world frame is metric)
gives ``base_mm = b`` and ``base_deg = a``; the residual says how well the marks, the
touches and the arm agree.
"""

from __future__ import annotations

import datetime
import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from feeder_bt.core.model import CellSpec

TOUCH_INSET_MM = 50.0         # default touch points: this far inside the pick window


@dataclass
class FrameFit:
    base_mm: tuple[float, float]
    base_deg: float
    rms_mm: float
    max_mm: float
    residuals_mm: list[float] = field(default_factory=list)

    def to_cell(self, xy_robot: tuple[float, float]) -> tuple[float, float]:
        a = math.radians(self.base_deg)
        x, y = xy_robot
        return (math.cos(a) * x - math.sin(a) * y + self.base_mm[0],
                math.sin(a) * x + math.cos(a) * y + self.base_mm[1])


def fit_frame(cell_pts: list[tuple[float, float]], robot_pts: list[tuple[float, float]]
              ) -> FrameFit:
    """Least-squares rigid fit of robot-world points onto cell points (at least two)."""
    c = np.asarray(cell_pts, dtype=float).reshape(-1, 2)
    w = np.asarray(robot_pts, dtype=float).reshape(-1, 2)
    if len(c) != len(w) or len(c) < 2:
        raise ValueError("the frame needs at least two touch points, each in both frames")
    cc, wc = c - c.mean(axis=0), w - w.mean(axis=0)
    if float(np.abs(wc).sum()) < 1e-6:
        raise ValueError("the touch points coincide: spread them over the pick window")
    a = math.atan2(float(np.sum(wc[:, 0] * cc[:, 1] - wc[:, 1] * cc[:, 0])),
                   float(np.sum(wc[:, 0] * cc[:, 0] + wc[:, 1] * cc[:, 1])))
    rot = np.array([[math.cos(a), -math.sin(a)], [math.sin(a), math.cos(a)]])
    b = c.mean(axis=0) - rot @ w.mean(axis=0)
    res = np.linalg.norm(w @ rot.T + b - c, axis=1)
    return FrameFit((float(b[0]), float(b[1])), math.degrees(a),
                    float(np.sqrt(np.mean(res ** 2))), float(res.max()),
                    [round(float(r), 3) for r in res])


def touch_points(cell: CellSpec, window: list[tuple[float, float]]) -> list[tuple[float, float]]:
    """``robot.touch_points_mm``, else three points spread over the pick window (corners
    ``window`` as ``pick_window`` gives them): two at its upstream edge, one downstream."""
    given = list(getattr(cell.robot, "touch_points_mm", []) or [])
    if given:
        return [(float(x), float(y)) for x, y in given]
    xs = [p[0] for p in window]
    ys = [p[1] for p in window]
    x0, x1, y0, y1 = min(xs), max(xs), min(ys), max(ys)
    m = TOUCH_INSET_MM
    return [(x0 + m, y0 + m), (x0 + m, y1 - m), (x1 - m, (y0 + y1) / 2)]


def frame_record(fit: FrameFit, cell_pts: list[tuple[float, float]],
                 robot_pts: list[tuple[float, float]]) -> dict[str, Any]:
    """What the frame file holds: the pose, and how it was found (a record for people)."""
    return {"base_mm": [round(fit.base_mm[0], 3), round(fit.base_mm[1], 3)],
            "base_deg": round(fit.base_deg, 4),
            "rms_mm": round(fit.rms_mm, 3), "max_mm": round(fit.max_mm, 3),
            "points": [{"cell": [round(c[0], 2), round(c[1], 2)],
                        "robot": [round(r[0], 2), round(r[1], 2)]}
                       for c, r in zip(cell_pts, robot_pts, strict=True)],
            "date": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds")}
