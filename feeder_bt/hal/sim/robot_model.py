"""Robot motion times: a trapezoidal profile on the Cartesian path, scaled by speed %.

Calibrated (cells/sim.yaml) so that the standard 25/305/25 mm cycle — up 25, across 305,
down 25, and back — takes 0.5 s at 100 %. An arch move (depart, traverse, approach) is
modelled as one profile over ``d + approach``: the vertical legs blend into the traverse.
Speed % scales the maximum speed by s and the acceleration by s², so times scale by 1/s.
"""

from __future__ import annotations

import math

from ...scenario.model import RobotSpec


def trapezoid_time(d: float, v_max: float, a_max: float) -> float:
    d = abs(d)
    if d <= 0.0:
        return 0.0
    d_ramp = v_max * v_max / a_max
    if d <= d_ramp:
        return 2.0 * math.sqrt(d / a_max)
    return 2.0 * v_max / a_max + (d - d_ramp) / v_max


class RobotModel:
    def __init__(self, spec: RobotSpec) -> None:
        self.spec = spec

    def arch_time(self, d_xy: float, speed_pct: float) -> float:
        s = max(speed_pct, 1e-3) / 100.0
        sp = self.spec
        return trapezoid_time(d_xy + sp.approach_mm, sp.v_max_mm_s * s, sp.a_max_mm_s2 * s * s)

    def standard_cycle(self, speed_pct: float = 100.0) -> float:
        """The 25/305/25 mm cycle, there and back."""
        return 2 * self.arch_time(305.0, speed_pct)

    def reachable(self, x: float, y: float) -> bool:
        bx, by = self.spec.base_mm
        r = math.hypot(x - bx, y - by)
        return self.spec.inner_reach_mm <= r <= self.spec.reach_mm
