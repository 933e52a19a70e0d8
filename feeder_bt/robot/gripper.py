"""Grip points and the gripper's footprint in the belt frame.

A part's ``pick`` (``scenario.model.PickSpec``) lists grips in the part's own frame and
the gripper's footprint: a suction cup (a disc) and/or finger boxes, in the grip's frame.
Placed at a part's pose (position, angle, face) they give where the robot should go and
what must be clear around it. Shared by the locator (which offers a free grip) and the
simulator (which judges a grip on a hole or on a neighbour as a miss); pure geometry.
"""

from __future__ import annotations

import math

import numpy as np

from feeder_bt.core.model import PickSpec

CUP_SEGMENTS = 24


def grip_poses(pick: PickSpec, x: float, y: float, angle_deg: float, mirrored: bool
               ) -> list[tuple[float, float, float]]:
    """Each grip's (x, y, angle) in the belt frame for a part at ``(x, y, angle_deg)``
    (its area centroid and angle); a face-down part's grips are mirrored with it."""
    a = math.radians(angle_deg)
    c, s = math.cos(a), math.sin(a)
    out = []
    for g in pick.grips:
        ox, oy = g.offset_mm
        ga = g.angle_deg
        if mirrored:                       # the outline is mirrored in y, then turned
            oy, ga = -oy, -ga
        out.append((x + c * ox - s * oy, y + s * ox + c * oy, angle_deg + ga))
    return out


def footprint(pick: PickSpec, x: float, y: float, angle_deg: float, grow_mm: float = 0.0
              ) -> list[np.ndarray]:
    """The gripper's footprint at a grip pose, as closed rings in belt mm (the cup's disc,
    each finger's box), each grown by ``grow_mm``."""
    rings: list[np.ndarray] = []
    if pick.cup_radius_mm > 0:
        r = pick.cup_radius_mm + grow_mm
        t = np.linspace(0.0, 2 * math.pi, CUP_SEGMENTS, endpoint=False)
        rings.append(np.stack([x + r * np.cos(t), y + r * np.sin(t)], axis=1))
    a = math.radians(angle_deg)
    rot = np.array([[math.cos(a), -math.sin(a)], [math.sin(a), math.cos(a)]])
    for f in pick.fingers:
        hx, hy = f.size_mm[0] / 2 + grow_mm, f.size_mm[1] / 2 + grow_mm
        box = np.array([[-hx, -hy], [hx, -hy], [hx, hy], [-hx, hy]]) + np.asarray(f.offset_mm)
        rings.append(box @ rot.T + np.array([x, y]))
    return rings
