"""V+ transformations (locations) and belt variables.

A transformation is a 4x4 homogeneous matrix. ``TRANS(x, y, z, y, p, r)``: a translation
and the rotation yaw about Z, then pitch about the new Y, then roll about the new Z (V+
Language Reference Guide, TRANS and DECOMPOSE: Z-Y-Z Euler angles; the decomposition of
a singular orientation, pitch 0 or 180, puts the whole turn into one angle: roll when
the tool points down, which is how the programs read the gripper's turn, yaw otherwise;
not confirmed which one V+ picks). ``a:b`` is the product (``b`` relative to ``a``),
``INVERSE`` the inverse.

A belt variable (``DEFBELT %b = nominal, encoder, vavg, scale``) is a frame that moves
along its nominal transformation's X axis by ``(count - latch) * scale`` mm (``SETBELT``
sets the latch); ``%b:loc`` is a location fixed to the belt (``BeltLoc``), which a
motion tracks.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np


class Trans:
    """A V+ transformation (location)."""

    __slots__ = ("m",)

    def __init__(self, m: np.ndarray) -> None:
        self.m = m

    @staticmethod
    def make(x: float = 0.0, y: float = 0.0, z: float = 0.0, yaw: float = 0.0,
             pitch: float = 0.0, roll: float = 0.0) -> Trans:
        m = np.eye(4)
        m[:3, :3] = _rz(yaw) @ _ry(pitch) @ _rz(roll)
        m[:3, 3] = (x, y, z)
        return Trans(m)

    def __matmul__(self, other: Trans) -> Trans:
        return Trans(self.m @ other.m)

    def inverse(self) -> Trans:
        r = self.m[:3, :3].T
        m = np.eye(4)
        m[:3, :3] = r
        m[:3, 3] = -r @ self.m[:3, 3]
        return Trans(m)

    @property
    def xyz(self) -> tuple[float, float, float]:
        return float(self.m[0, 3]), float(self.m[1, 3]), float(self.m[2, 3])

    def decompose(self) -> tuple[float, float, float, float, float, float]:
        """x, y, z, yaw, pitch, roll (deg), pitch in 0..180."""
        r = self.m[:3, :3]
        x, y, z = self.xyz
        s = math.hypot(r[0, 2], r[1, 2])
        pitch = math.degrees(math.atan2(s, r[2, 2]))
        if s > 1e-9:
            yaw = math.degrees(math.atan2(r[1, 2], r[0, 2]))
            roll = math.degrees(math.atan2(r[2, 1], -r[2, 0]))
        elif r[2, 2] < 0:                     # pitch 180, tool down: Ry(180) Rz(roll)
            yaw, roll = 0.0, math.degrees(math.atan2(r[1, 0], r[1, 1]))
        else:                                 # pitch 0: Rz(yaw)
            yaw, roll = math.degrees(math.atan2(r[1, 0], r[0, 0])), 0.0
        return x, y, z, _wrap(yaw), pitch, _wrap(roll)

    def shifted_tool_z(self, d: float) -> Trans:
        """The location ``d`` mm along its own tool Z axis (APPRO, DEPARTS: ``-d``)."""
        return self @ Trans.make(0.0, 0.0, d)

    def __repr__(self) -> str:
        return "Trans(" + ", ".join(f"{v:.3f}" for v in self.decompose()) + ")"


def _wrap(deg: float) -> float:
    deg = (deg + 180.0) % 360.0 - 180.0
    return 0.0 if abs(deg) < 1e-9 else deg


def _rz(deg: float) -> np.ndarray:
    c, s = math.cos(math.radians(deg)), math.sin(math.radians(deg))
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def _ry(deg: float) -> np.ndarray:
    c, s = math.cos(math.radians(deg)), math.sin(math.radians(deg))
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


@dataclass
class Belt:
    """A V+ belt variable. ``count`` reads the robot's belt channel (24-bit signed)."""

    name: str
    nominal: Trans = field(default_factory=Trans.make)
    encoder: int = 1
    vavg: float = 16.0
    scale: float = 1.0
    latch: int = 0
    window: tuple[float, float] | None = None     # upstream, downstream belt x (mm)
    window_program: str = ""

    def travel(self, count: int) -> float:
        """mm the belt moved since the latch (the 24-bit counter may have rolled over)."""
        d = (count - self.latch + (1 << 23)) % (1 << 24) - (1 << 23)
        return d * self.scale

    def frame(self, count: int) -> Trans:
        return self.nominal @ Trans.make(self.travel(count))


@dataclass
class BeltLoc:
    """``%belt:loc``: a location fixed to the belt; where it is depends on the count."""

    belt: Belt
    loc: Trans

    def at(self, count: int) -> Trans:
        return self.belt.frame(count) @ self.loc

    def belt_x(self, count: int) -> float:
        """The location's x along the belt from the nominal frame (the WINDOW test)."""
        return self.loc.xyz[0] + self.belt.travel(count)

    def shifted_tool_z(self, d: float) -> BeltLoc:
        return BeltLoc(self.belt, self.loc.shifted_tool_z(d))
