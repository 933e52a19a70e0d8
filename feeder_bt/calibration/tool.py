"""Tool offset: where the gripper's tip is in the flange frame.

The robot touches one fixed point with the tool turned to several angles. With the flange
at ``f_i`` turned ``rz_i``, the tip is at ``f_i + R(rz_i) d`` = the point ``P`` every time:
``R(rz_i) d - P = -f_i``, linear in ``(d, P)``. Two touches at different angles fix it;
more average the touch errors out, and angles far apart condition it best.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from feeder_bt.calibration.procedure import CalibrationError, Waiter, rms_max
from feeder_bt.core.geometry import wrap_deg
from feeder_bt.core.jobs import Job
from feeder_bt.hal.interfaces import Hal

MIN_TOUCHES = 2
MIN_SPREAD_DEG = 20.0


@dataclass(frozen=True)
class ToolTouch:
    """The flange pose (robot frame) with the tool tip on the fixed point."""

    x_mm: float
    y_mm: float
    rz_deg: float


@dataclass
class ToolFit:
    offset_mm: tuple[float, float]
    point_mm: tuple[float, float]        # the touched point, robot frame
    rms_mm: float
    max_mm: float
    n_touches: int

    def as_dict(self) -> dict:
        return {"tool_offset_mm": [round(self.offset_mm[0], 4), round(self.offset_mm[1], 4)],
                "point_mm": [round(self.point_mm[0], 3), round(self.point_mm[1], 3)],
                "residual_mm": {"rms": round(self.rms_mm, 4), "max": round(self.max_mm, 4)},
                "touches": self.n_touches}


def _spread_deg(angles: Sequence[float]) -> float:
    """The largest angle between any two of ``angles`` (0..180)."""
    return max((abs(wrap_deg(a - b)) for a in angles for b in angles), default=0.0)


def fit_tool(touches: Sequence[ToolTouch]) -> ToolFit:
    """Least-squares tool offset ``(dx, dy)`` from touches of one point."""
    if len(touches) < MIN_TOUCHES:
        raise CalibrationError(f"need at least {MIN_TOUCHES} touches of the point with "
                               f"different tool angles, got {len(touches)}")
    f = np.array([[t.x_mm, t.y_mm] for t in touches], dtype=float)
    rz = np.radians([t.rz_deg for t in touches])
    if not (np.isfinite(f).all() and np.isfinite(rz).all()):
        raise CalibrationError("a touch pose is not a finite number")
    spread = _spread_deg([t.rz_deg for t in touches])
    if spread < MIN_SPREAD_DEG:
        raise CalibrationError(f"the tool angles span only {spread:.1f} deg: touch the point "
                               f"with angles at least {MIN_SPREAD_DEG:g} deg apart "
                               "(90 deg or more is best)")
    c, s = np.cos(rz), np.sin(rz)
    n = len(touches)
    one, zero = np.ones(n), np.zeros(n)
    a_mat = np.vstack([np.column_stack([c, -s, -one, zero]),
                       np.column_stack([s, c, zero, -one])])
    rhs = -np.concatenate([f[:, 0], f[:, 1]])
    (dx, dy, px, py), *_ = np.linalg.lstsq(a_mat, rhs, rcond=None)
    tips = f + np.column_stack([c * dx - s * dy, s * dx + c * dy])
    rms, mx = rms_max(tips - np.array([px, py]))
    return ToolFit((float(dx), float(dy)), (float(px), float(py)), rms, mx, n)


def tool_procedure(hal: Hal, wait: Waiter, touch_point: Callable[[float], Job],
                   angles_deg: Sequence[float] = (-90.0, -30.0, 30.0, 90.0),
                   settle: Callable[[], None] | None = None) -> ToolFit:
    """The guided procedure: touch the fixed point with the tool at each angle.

    ``touch_point(rz)`` puts the tip on the point with the tool turned ``rz`` (robot frame)
    and returns a job that ends when it is there.
    """
    touches = []
    for rz in angles_deg:
        wait(touch_point(rz))
        if settle is not None:
            settle()                 # a real controller: read the pose after the touch
        pose = hal.robot_position.pose()
        touches.append(ToolTouch(pose.x, pose.y, pose.rz))
    wait(hal.robot.move_safe())
    return fit_tool(touches)
