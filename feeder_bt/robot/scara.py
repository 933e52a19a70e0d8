"""A two-link SCARA's move times from its joints: the plant's robot.

The controller prices moves with a Cartesian trapezoid (``robot_model.RobotModel``, and the
fit of it the pick policies learn, ``robot/fit.py``). A real SCARA does not move like that:
its time follows the joints. This model is the *world's* arm — the simulated robot
(``hal/sim``) and the V+ emulator's arm (``emulators/vplus/arm.py``) use it — so the
controller's model only approximates it, as on a real cell.

Kinematics (Adept Cobra 600 class; figures and sources in docs/simulator.md, "Robot"):

- two links in the plane, inner 325 mm and outer 275 mm (reach 600 mm); the inverse
  kinematics takes one elbow configuration for every pose (``elbow``: ``"lefty"`` or
  ``"righty"``), so the arm never flips mid-run. Lefty by default: the Adept Cobra
  PLC600/PLC800 Robot User's Guide rev C p. 90 gives the motion qualifier bits with
  their "bit off" meanings trapezoidal acceleration, joint motion and *lefty* arm
  configuration (both configurations reach this cell's window with joint 1 inside a
  210° range; which one a cell was taught is checked at commissioning);
- a joint-interpolated move: every joint runs a trapezoid under its own speed and
  acceleration limits and all start and stop together, so the move takes the slowest
  joint's time ("the maximum speed is gated by the slowest-moving joint during the
  motion, since all the joints are required to start and stop at the same time": Adept
  Cobra PLC600 User's Guide, 10.1 "Understanding Robot Motion Parameters");
- an arch (depart up ``approach_mm``, transfer, approach down) is three motions run in
  continuous path (V+ Language User's Guide ch. 8): each motion's acceleration overlaps the
  previous one's deceleration, so the arch takes the three times less the two overlaps;
- SPEED s % scales every joint's speed by s and its acceleration by s² (an assumption:
  V+'s SPEED scales speed; ACCEL is a separate setting. With both scaled, times scale by
  1/s, as the controller's Cartesian model assumes too).

Every function is closed-form; ``arch_times`` prices many moves at once with numpy.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np

from feeder_bt.core.model import RobotSpec, SimImperfections
from feeder_bt.robot.model import RobotModel

# Cobra 600 class figures (docs/simulator.md, "Robot", says which are published and which
# are assumptions). Speeds: the Cobra s600 data sheet's joint speeds (not confirmed by the
# search tool: an assumption to check at commissioning). RAMP_S: the time every joint takes
# to reach full speed, the one figure calibrated (no acceleration is published) so that the
# Adept cycle (ADEPT_CYCLE_*) takes 0.5 s at 100 %.
INNER_MM = 325.0
OUTER_MM = 275.0
J1_DEG_S = 386.0
J2_DEG_S = 720.0
Z_MM_S = 1100.0
RAMP_S = 0.065
# the Adept cycle: up 25 mm, across 305 mm, down 25 mm, and back (where in the envelope is
# not published: here a chord across the base's x axis at 400 mm, both ends at the same
# radius, so joint 1 alone moves in the plane)
ADEPT_CYCLE_Z_MM = 25.0
ADEPT_CYCLE_CHORD = ((400.0, -152.5), (400.0, 152.5))


def trapezoid(d: float, v: float, a: float) -> tuple[float, float]:
    """(time, ramp time) of a rest-to-rest trapezoid (a triangle when short) over ``d``."""
    d = abs(d)
    if d <= 0.0:
        return 0.0, 0.0
    if d * a <= v * v:
        ramp = math.sqrt(d / a)
        return 2.0 * ramp, ramp
    return v / a + d / v, v / a


def _trapezoids(d: np.ndarray, v: float, a: float) -> tuple[np.ndarray, np.ndarray]:
    """``trapezoid`` for many distances at once."""
    d = np.abs(d)
    short = d * a <= v * v
    ramp = np.where(short, np.sqrt(d / a), v / a)
    return np.where(short, 2.0 * ramp, v / a + d / v), ramp


@dataclass(frozen=True)
class ScaraSpec:
    """The arm's joints: link lengths, limits per joint (rad, mm), elbow configuration."""

    inner_mm: float = INNER_MM
    outer_mm: float = OUTER_MM
    j1_rad_s: float = math.radians(J1_DEG_S)
    j2_rad_s: float = math.radians(J2_DEG_S)
    z_mm_s: float = Z_MM_S
    j1_rad_s2: float = math.radians(J1_DEG_S) / RAMP_S
    j2_rad_s2: float = math.radians(J2_DEG_S) / RAMP_S
    z_mm_s2: float = Z_MM_S / RAMP_S
    elbow: str = "lefty"

    def scaled(self, factor: float) -> ScaraSpec:
        """The same arm ``factor`` times as fast (speeds × f, accelerations × f²)."""
        f2 = factor * factor
        return dataclasses.replace(
            self, j1_rad_s=self.j1_rad_s * factor, j2_rad_s=self.j2_rad_s * factor,
            z_mm_s=self.z_mm_s * factor, j1_rad_s2=self.j1_rad_s2 * f2,
            j2_rad_s2=self.j2_rad_s2 * f2, z_mm_s2=self.z_mm_s2 * f2)


class ScaraModel(RobotModel):
    """The world's arm: the cell's robot (base, reach, grip and release times) moving as a
    SCARA. Poses are in the cell frame; ``move_time`` and ``arch_time_between`` need both
    ends (a SCARA's time is not a function of the distance alone)."""

    def __init__(self, spec: RobotSpec, scara: ScaraSpec | None = None) -> None:
        super().__init__(spec)
        self.scara = scara or ScaraSpec()
        if self.scara.elbow not in ("lefty", "righty"):
            raise ValueError(f"scara elbow: {self.scara.elbow!r} is not lefty or righty")
        self._sign = 1.0 if self.scara.elbow == "righty" else -1.0
        th = math.radians(spec.base_deg)
        self._cos, self._sin = math.cos(th), math.sin(th)
        self._starts: dict[tuple[float, float], tuple[np.ndarray, np.ndarray]] = {}

    def arch_time(self, d_xy: float, speed_pct: float) -> float:
        raise TypeError("a SCARA's move time needs both ends: use move_time(a, b, speed)")

    def arch_times(self, d_xy: np.ndarray, speed_pct: float) -> np.ndarray:
        raise TypeError("a SCARA's move time needs both ends: use arch_times_from")

    # ------------------------------------------------------------ kinematics
    def joints(self, x: np.ndarray | float, y: np.ndarray | float
               ) -> tuple[np.ndarray, np.ndarray]:
        """(q1, q2) in rad for cell-frame points (a point beyond the reach is taken at the
        reach: the elbow straight)."""
        bx, by = self.spec.base_mm
        dx, dy = np.asarray(x, dtype=float) - bx, np.asarray(y, dtype=float) - by
        rx, ry = self._cos * dx + self._sin * dy, -self._sin * dx + self._cos * dy
        s = self.scara
        l1, l2 = s.inner_mm, s.outer_mm
        c2 = (rx * rx + ry * ry - l1 * l1 - l2 * l2) / (2.0 * l1 * l2)
        # np.minimum/np.maximum: np.clip's values (NaN too) without its dispatch overhead
        q2 = self._sign * np.arccos(np.minimum(np.maximum(c2, -1.0), 1.0))
        q1 = np.arctan2(ry, rx) - np.arctan2(l2 * np.sin(q2), l1 + l2 * np.cos(q2))
        return q1, q2

    def _start_joints(self, start: tuple[float, float]) -> tuple[np.ndarray, np.ndarray]:
        """``joints`` of a move's start, kept: a run's moves start from a few poses (the
        place poses, the safe pose), and the replay of ``analysis.robot_bounds`` asks
        thousands of times."""
        key = (float(start[0]), float(start[1]))
        cache = self._starts
        got = cache.get(key)
        if got is None:
            if len(cache) > 256:
                cache.clear()
            got = cache[key] = self.joints(start[0], start[1])
        return got

    def _joint(self, x: float, y: float) -> tuple[float, float]:
        """``joints`` for one point, in plain floats (the simulated robot's every move)."""
        bx, by = self.spec.base_mm
        dx, dy = x - bx, y - by
        rx, ry = self._cos * dx + self._sin * dy, -self._sin * dx + self._cos * dy
        l1, l2 = self.scara.inner_mm, self.scara.outer_mm
        c2 = (rx * rx + ry * ry - l1 * l1 - l2 * l2) / (2.0 * l1 * l2)
        q2 = self._sign * math.acos(min(max(c2, -1.0), 1.0))
        return math.atan2(ry, rx) - math.atan2(l2 * math.sin(q2), l1 + l2 * math.cos(q2)), q2

    def _transfer(self, a: tuple[float, float], b: tuple[float, float], s: float
                  ) -> tuple[float, float]:
        """(time, ramp time) of the joint-interpolated move a → b in the plane."""
        p1, p2 = self._joint(a[0], a[1])
        q1, q2 = self._joint(b[0], b[1])
        d1 = abs(math.remainder(q1 - p1, math.tau))
        d2 = abs(q2 - p2)
        sc = self.scara
        t1 = trapezoid(d1, sc.j1_rad_s * s, sc.j1_rad_s2 * s * s)
        t2 = trapezoid(d2, sc.j2_rad_s * s, sc.j2_rad_s2 * s * s)
        return max(t1, t2)

    def _z(self, s: float) -> tuple[float, float]:
        sc = self.scara
        return trapezoid(self.spec.approach_mm, sc.z_mm_s * s, sc.z_mm_s2 * s * s)

    def move_time(self, a: tuple[float, float], b: tuple[float, float],
                  speed_pct: float) -> float:
        """An arch a → b: depart, transfer, approach in continuous path (see the module)."""
        s = max(speed_pct, 1e-3) / 100.0
        tz, rz = self._z(s)
        tt, rt = self._transfer(a, b, s)
        return 2.0 * tz + tt - 2.0 * min(rz, rt)

    def segment_time(self, a: tuple[float, float, float], b: tuple[float, float, float],
                     speed_pct: float) -> tuple[float, float]:
        """(time, ramp time) of one joint-interpolated motion between 3-D poses given in
        the robot's own frame (the V+ emulator's motions: J1, J2 and Z together)."""
        s = max(speed_pct, 1e-3) / 100.0
        c, sn = self._cos, self._sin
        bx, by = self.spec.base_mm        # back to the cell frame that ``joints`` takes
        pa = (bx + c * a[0] - sn * a[1], by + sn * a[0] + c * a[1])
        pb = (bx + c * b[0] - sn * b[1], by + sn * b[0] + c * b[1])
        sc = self.scara
        tz = trapezoid(b[2] - a[2], sc.z_mm_s * s, sc.z_mm_s2 * s * s)
        return max(self._transfer(pa, pb, s), tz)

    def arch_times_from(self, start: tuple[float, float], x: np.ndarray, y: np.ndarray,
                        speed_pct: float) -> np.ndarray:
        """``move_time`` from ``start`` to many points at once."""
        s = max(speed_pct, 1e-3) / 100.0
        tz, rz = self._z(s)
        q1, q2 = self.joints(x, y)
        p1, p2 = self._start_joints(start)
        d1 = np.abs(np.remainder(q1 - p1 + math.pi, math.tau) - math.pi)
        sc = self.scara
        t1, r1 = _trapezoids(d1, sc.j1_rad_s * s, sc.j1_rad_s2 * s * s)
        t2, r2 = _trapezoids(q2 - p2, sc.j2_rad_s * s, sc.j2_rad_s2 * s * s)
        tt = np.maximum(t1, t2)
        rt = np.where(t1 >= t2, r1, r2)
        return 2.0 * tz + tt - 2.0 * np.minimum(rz, rt)

    def standard_cycle(self, speed_pct: float = 100.0) -> float:
        """The Adept cycle, there and back (``ADEPT_CYCLE_CHORD`` in the robot's frame)."""
        (ax, ay), (bx_, by_) = ADEPT_CYCLE_CHORD
        c, sn = self._cos, self._sin
        bx, by = self.spec.base_mm
        a = (bx + c * ax - sn * ay, by + sn * ax + c * ay)
        b = (bx + c * bx_ - sn * by_, by + sn * bx_ + c * by_)
        return self.move_time(a, b, speed_pct) + self.move_time(b, a, speed_pct)

    def best_pick_point(self, place: tuple[float, float],
                        window: tuple[float, float, float, float]) -> tuple[float, float] | None:
        """The reachable point of ``window`` with the shortest round trip from ``place``
        (for a SCARA not the nearest point: joint 2 is faster than joint 1)."""
        x_lo, x_hi, y_lo, y_hi = window
        xs, ys = np.meshgrid(np.linspace(x_lo, x_hi, 201), np.linspace(y_lo, y_hi, 201))
        x, y = xs.ravel(), ys.ravel()
        ok = self.reachable_mask(x, y)
        if not ok.any():
            return None
        x, y = x[ok], y[ok]
        t = 2.0 * self.arch_times_from(place, x, y, 100.0)   # symmetric: there and back
        i = int(np.argmin(t))
        return float(x[i]), float(y[i])


def world_arm(spec: RobotSpec, speed_factor: float = 1.0,
              joints: SimImperfections | None = None) -> ScaraModel:
    """The simulated world's arm for the cell's robot: a Cobra 600 shaped to the cell's
    reach (both links scaled to sum to ``reach_mm``) and timed so its Adept cycle is the
    one the cell's description was calibrated to (cells/sim.yaml: 0.5 s; the original
    cell's Adept 550: 0.7 s), times ``speed_factor`` (the cell's ``sim_speed_factor``: a
    study's slower or faster arm).

    ``joints`` (a world's ``sim:`` figures, ``arm_*``): each joint limit it gives (> 0) is
    the arm's truth, whatever the robot description says; so a world file can hold an arm
    the cell file describes wrongly."""
    k = spec.reach_mm / (INNER_MM + OUTER_MM)
    shape = ScaraSpec(inner_mm=INNER_MM * k, outer_mm=OUTER_MM * k)
    f = ScaraModel(spec, shape).standard_cycle() / RobotModel(spec).standard_cycle()
    arm = shape.scaled(f)
    if joints is not None:
        given = {name: value for name, value in (
            ("j1_rad_s", math.radians(joints.arm_j1_deg_s)),
            ("j2_rad_s", math.radians(joints.arm_j2_deg_s)),
            ("z_mm_s", joints.arm_z_mm_s),
            ("j1_rad_s2", math.radians(joints.arm_j1_deg_s2)),
            ("j2_rad_s2", math.radians(joints.arm_j2_deg_s2)),
            ("z_mm_s2", joints.arm_z_mm_s2)) if value > 0.0}
        arm = dataclasses.replace(arm, **given)
    return ScaraModel(spec, arm.scaled(speed_factor))


def arm_figures(arm: ScaraSpec) -> dict[str, float]:
    """The arm's joint limits as a world file's ``sim:`` keys (degrees, mm)."""
    return {"arm_j1_deg_s": math.degrees(arm.j1_rad_s), "arm_j2_deg_s": math.degrees(arm.j2_rad_s),
            "arm_z_mm_s": arm.z_mm_s, "arm_j1_deg_s2": math.degrees(arm.j1_rad_s2),
            "arm_j2_deg_s2": math.degrees(arm.j2_rad_s2), "arm_z_mm_s2": arm.z_mm_s2}
