"""Belt <-> robot: how far the belt moves per encoder count, and which way, in the robot frame.

A marker stuck on the belt is touched by the robot at several belt positions; each touch
records the robot's tool position and the robot controller's belt count (24-bit, wrapping:
counts are unwrapped with ``feeder_bt.core.encoder.diff``, right as long as the belt moves less
than half a wrap between touches). The touches lie on a line ``p = p0 + c * m`` where ``c``
is counts since the first touch and ``m`` the belt's motion per count in the robot frame;
``counts_per_mm = 1 / |m|`` and the direction is the angle of ``m``.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from feeder_bt.calibration.procedure import CalibrationError, Waiter, rms_max
from feeder_bt.core.encoder import diff
from feeder_bt.core.jobs import Job
from feeder_bt.hal.interfaces import Hal

MIN_TOUCHES = 3
MIN_TRAVEL_MM = 50.0
# The cell frame's x is the belt's travel (vplus/PROTOCOL.md, "Frames"). A frame turned by
# this much from it puts a part tracked 600 mm about 1 mm across the belt from where the
# controller thinks it is: over it, a calibration says so and gives the frame square to the
# travel.
TRAVEL_LIMIT_DEG = 0.1


@dataclass(frozen=True)
class BeltTouch:
    """The robot's tool on the marker: its position (robot frame, mm) and belt count."""

    x_mm: float
    y_mm: float
    encoder: int


@dataclass
class BeltFit:
    counts_per_mm: float
    direction_deg: float          # angle of the belt's travel in the robot frame
    direction: tuple[float, float]
    rms_mm: float
    max_mm: float
    travel_mm: float
    n_touches: int

    def as_dict(self) -> dict:
        return {"counts_per_mm": round(self.counts_per_mm, 6),
                "direction_deg": round(self.direction_deg, 5),
                "direction": [round(self.direction[0], 7), round(self.direction[1], 7)],
                "residual_mm": {"rms": round(self.rms_mm, 4), "max": round(self.max_mm, 4)},
                "travel_mm": round(self.travel_mm, 2), "touches": self.n_touches}


def unwrap_counts(encoders: Sequence[int], bits: int) -> np.ndarray:
    """Counts since the first reading, across roll-over of a ``bits``-wide counter."""
    out = [0]
    for prev, cur in zip(encoders, encoders[1:], strict=False):
        out.append(out[-1] + diff(int(cur), int(prev), bits))
    return np.asarray(out, dtype=float)


def fit_belt(touches: Sequence[BeltTouch], robot_bits: int = 24) -> BeltFit:
    """Least-squares line through the touches against unwrapped counts."""
    if len(touches) < MIN_TOUCHES:
        raise CalibrationError(f"need at least {MIN_TOUCHES} touches of the marker at "
                               f"different belt positions, got {len(touches)}")
    c = unwrap_counts([t.encoder for t in touches], robot_bits)
    p = np.array([[t.x_mm, t.y_mm] for t in touches], dtype=float)
    if not np.isfinite(p).all():
        raise CalibrationError("a touch position is not a finite number")
    if np.ptp(c) == 0:
        raise CalibrationError("the belt count did not change between touches: move the "
                               "belt between touches (is the encoder connected?)")
    a_mat = np.column_stack([np.ones(len(c)), c])
    (p0, m), *_ = np.linalg.lstsq(a_mat, p, rcond=None)
    mm_per_count = float(np.hypot(*m))
    travel = mm_per_count * float(np.ptp(c))
    if travel < MIN_TRAVEL_MM:
        raise CalibrationError(f"the touches span only {travel:.1f} mm of belt travel: spread "
                               f"them over at least {MIN_TRAVEL_MM:g} mm")
    rms, mx = rms_max(a_mat @ np.vstack([p0, m]) - p)
    u = m / mm_per_count
    return BeltFit(counts_per_mm=1.0 / mm_per_count,
                   direction_deg=math.degrees(math.atan2(u[1], u[0])),
                   direction=(float(u[0]), float(u[1])), rms_mm=rms, max_mm=mx,
                   travel_mm=travel, n_touches=len(touches))


def belt_procedure(hal: Hal, wait: Waiter, touch_marker: Callable[[], Job],
                   steps_mm: Sequence[float] = (80.0, 80.0, 80.0, 80.0),
                   speed_mm_s: float = 100.0, conveyor: str = "horizontal",
                   robot_bits: int = 24,
                   settle: Callable[[], None] | None = None) -> BeltFit:
    """The guided procedure: touch the marker, advance the belt by each step, touch again.

    ``touch_marker`` puts the tool on the marker (the operator with a pendant, or the
    simulator's rig) and returns a job that ends when it is there; ``settle`` (optional)
    runs after each touch, before the pose and count are read.
    """
    belt = hal.conveyors[conveyor]
    hal.motors_on()                  # the person who runs the calibration asks for the SH
    touches = []
    for k in range(len(steps_mm) + 1):
        if k:
            wait(hal.robot.move_safe())
            wait(belt.move(steps_mm[k - 1], speed_mm_s))
        wait(touch_marker())
        if settle is not None:
            settle()                 # a real controller: read the pose after the touch
        pose = hal.robot_position.pose()
        touches.append(BeltTouch(pose.x, pose.y, hal.robot_position.belt_encoder()))
    wait(hal.robot.move_safe())
    return fit_belt(touches, robot_bits)


def travel_deg(moves_mm: Sequence[tuple[float, float]]) -> float:
    """The belt's direction of travel in a frame (degrees from its x axis, -90..90): the
    principal direction of a marker's displacements (each from where it was at rest) as
    the belt carried it, seen in that frame (a camera's calibration, a robot's)."""
    d = np.asarray(moves_mm, dtype=float).reshape(-1, 2)
    if len(d) < 2 or float(np.hypot(d[:, 0], d[:, 1]).max(initial=0.0)) < MIN_TRAVEL_MM:
        raise CalibrationError(f"the marker must travel at least {MIN_TRAVEL_MM:g} mm in view "
                               "to give the belt's direction")
    sxx, syy, sxy = float(d[:, 0] @ d[:, 0]), float(d[:, 1] @ d[:, 1]), float(d[:, 0] @ d[:, 1])
    deg = math.degrees(0.5 * math.atan2(2.0 * sxy, sxx - syy))
    return deg


def travel_in_cell_deg(fit: BeltFit, base_deg: float) -> float:
    """The belt's travel in the cell frame, from the belt calibration's direction in the
    robot frame and the robot's turn in the cell (``robot.base_deg``): 0 when the cell
    frame's x is the travel, as it must be."""
    return (fit.direction_deg + base_deg + 180.0) % 360.0 - 180.0
