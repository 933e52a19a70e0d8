"""Robot motion times: a trapezoidal profile on the Cartesian path, scaled by speed %.

Calibrated (cells/sim.yaml) so that the standard 25/305/25 mm cycle — up 25, across 305,
down 25, and back — takes 0.5 s at 100 %. An arch move (depart, traverse, approach) is
modelled as one profile over ``d + approach``: the vertical legs blend into the traverse.
Speed % scales the maximum speed by s and the acceleration by s², so times scale by 1/s.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from feeder_bt.core.model import RobotSpec


def trapezoid_time(d: float, v_max: float, a_max: float) -> float:
    d = abs(d)
    if d <= 0.0:
        return 0.0
    d_ramp = v_max * v_max / a_max
    if d <= d_ramp:
        return 2.0 * math.sqrt(d / a_max)
    return 2.0 * v_max / a_max + (d - d_ramp) / v_max


def with_speed_factor(spec: RobotSpec, factor: float) -> RobotSpec:
    """The same robot ``factor`` times as fast: v_max times f, a_max times f², so every
    move takes 1/f as long (how speed % scales a move, applied to the limits)."""
    return dataclasses.replace(spec, v_max_mm_s=spec.v_max_mm_s * factor,
                               a_max_mm_s2=spec.a_max_mm_s2 * factor * factor)


class RobotModel:
    def __init__(self, spec: RobotSpec) -> None:
        self.spec = spec

    def arch_time(self, d_xy: float, speed_pct: float) -> float:
        s = max(speed_pct, 1e-3) / 100.0
        sp = self.spec
        return trapezoid_time(d_xy + sp.approach_mm, sp.v_max_mm_s * s, sp.a_max_mm_s2 * s * s)

    def arch_times(self, d_xy: np.ndarray, speed_pct: float) -> np.ndarray:
        """``arch_time`` for many moves at once (a pick policy prices a whole queue)."""
        s = max(speed_pct, 1e-3) / 100.0
        sp = self.spec
        v, a = sp.v_max_mm_s * s, sp.a_max_mm_s2 * s * s
        d = np.abs(d_xy) + sp.approach_mm
        ramp = v * v / a
        short = 2.0 * np.sqrt(d / a)
        return np.where(d <= ramp, short, 2.0 * v / a + (d - ramp) / v)

    def move_time(self, a: tuple[float, float], b: tuple[float, float],
                  speed_pct: float) -> float:
        """An arch from ``a`` to ``b`` (cell frame): here a function of the distance alone;
        the world's SCARA (``feeder_bt.robot.scara``) needs both ends."""
        return self.arch_time(math.dist(a, b), speed_pct)

    def arch_times_from(self, start: tuple[float, float], x: np.ndarray, y: np.ndarray,
                        speed_pct: float) -> np.ndarray:
        """``move_time`` from ``start`` to many points at once."""
        return self.arch_times(np.hypot(x - start[0], y - start[1]), speed_pct)

    def standard_cycle(self, speed_pct: float = 100.0) -> float:
        """The 25/305/25 mm cycle, there and back."""
        return 2 * self.arch_time(305.0, speed_pct)

    def reachable(self, x: float, y: float) -> bool:
        bx, by = self.spec.base_mm
        r = math.hypot(x - bx, y - by)
        return self.spec.inner_reach_mm <= r <= self.spec.reach_mm

    def reachable_mask(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """``reachable`` for many points at once."""
        bx, by = self.spec.base_mm
        r = np.hypot(x - bx, y - by)
        return (r >= self.spec.inner_reach_mm) & (r <= self.spec.reach_mm)

    def pick_place_time(self, start: tuple[float, float], pick: tuple[float, float],
                        place: tuple[float, float], speed_pct: float,
                        tracking: bool = True) -> float:
        """One pick-and-place from ``start``: arch to the pick, (settle), grip, arch to the
        place, release — the same sum the simulated robot's jobs take."""
        sp = self.spec
        return (self.move_time(start, pick, speed_pct)
                + (sp.track_settle_s if tracking else 0.0) + sp.grip_s
                + self.move_time(pick, place, speed_pct) + sp.release_s
                + 2 * sp.command_overhead_s)

    def best_pick_point(self, place: tuple[float, float],
                        window: tuple[float, float, float, float]) -> tuple[float, float] | None:
        """The reachable point of ``window`` (x_lo, x_hi, y_lo, y_hi) nearest ``place``:
        where a part would have to lie for the shortest possible cycle; None if none is."""
        x_lo, x_hi, y_lo, y_hi = window
        near = (min(max(place[0], x_lo), x_hi), min(max(place[1], y_lo), y_hi))
        if self.reachable(*near):
            return near
        best: tuple[float, float] | None = None
        steps = 200
        for i in range(steps + 1):           # the reach cuts the rectangle: search it
            x = x_lo + (x_hi - x_lo) * i / steps
            for j in range(steps + 1):
                y = y_lo + (y_hi - y_lo) * j / steps
                if self.reachable(x, y) and (best is None
                                             or math.dist((x, y), place) < math.dist(best, place)):
                    best = (x, y)
        return best

    def shortest_cycle(self, place: tuple[float, float],
                       window: tuple[float, float, float, float], speed_pct: float,
                       tracking: bool = True) -> float | None:
        """The shortest pick-and-place cycle the model allows: start at the place pose,
        pick at the best point of ``window``, come back and release. Throughput can never
        beat ``60 / shortest_cycle`` parts/min at this speed."""
        pick = self.best_pick_point(place, window)
        if pick is None:
            return None
        return self.pick_place_time(place, pick, place, speed_pct, tracking)
