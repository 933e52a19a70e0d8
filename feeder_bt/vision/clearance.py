"""Gripper clearance: which grip of a located part the robot can use.

A part whose ``pick`` (``scenario.model.PickSpec``) lists grips and a footprint (a cup,
fingers) is offered at the first of its grips whose footprint, grown by
``clearance_mm``, covers no pixel of any other blob in the frame (a neighbour, a part cut
by the border, a clump it was not part of): commercial feeders check the same before they
hand a part to the robot. If every grip is blocked the part is rejected ("gripper
blocked") and waits for a later frame or its next pass. Only pixels are read: the other
blobs' contours and the part's own pose as located. A footprint reaching out of the image
is judged on what the image shows.
"""

from __future__ import annotations

import cv2
import numpy as np

from feeder_bt.core.model import PartSpec
from feeder_bt.robot.gripper import footprint, grip_poses
from feeder_bt.vision.blobs import Blob
from feeder_bt.vision.pixels import Calibration


def offer_grips(blobs: list[Blob], parts: dict[str, PartSpec],
                calibration: Calibration, check: bool = True) -> None:
    """Set each accepted, pickable blob's grip (``Detection.grip_dx_mm``/``grip_dy_mm``)
    to its first free grip, or reject it as "gripper blocked". ``check`` false (the
    recipe's ``check_clearance``): the first grip, nothing looked at."""
    for b in blobs:
        det = b.det
        if det.reason or not det.pickable or det.part is None:
            continue
        spec = parts[det.part]
        pick = spec.pick
        if pick is None:
            continue
        mirrored = spec.poses[det.pose].mirror if det.pose in spec.poses else False
        for gx, gy, ga in grip_poses(pick, det.x_mm, det.y_mm, det.angle_deg, mirrored):
            rings = footprint(pick, gx, gy, ga, pick.clearance_mm)
            if not check or not rings or not _blocked(rings, b, blobs, calibration):
                det.grip_dx_mm, det.grip_dy_mm = gx - det.x_mm, gy - det.y_mm
                det.grip_deg = ga - det.angle_deg
                break
        else:
            det.reason = "gripper blocked"


def _blocked(rings_mm: list[np.ndarray], own: Blob, blobs: list[Blob],
             calibration: Calibration) -> bool:
    """Whether the footprint's rings cover a pixel of another blob than ``own``."""
    px = [calibration.mm_to_px(r) for r in rings_mm]
    allpx = np.concatenate(px)
    u0, v0 = np.floor(allpx.min(axis=0)).astype(int) - 1
    u1, v1 = np.ceil(allpx.max(axis=0)).astype(int) + 2
    near = [o for o in blobs if o is not own and o.box[0] < u1 and o.box[0] + o.box[2] > u0
            and o.box[1] < v1 and o.box[1] + o.box[3] > v0]
    if not near:
        return False
    w, h = int(u1 - u0), int(v1 - v0)
    foot = np.zeros((h, w), np.uint8)
    for p in px:                  # one at a time: overlapping rings must not cancel
        cv2.fillPoly(foot, [np.round(p - (u0, v0)).astype(np.int32).reshape(-1, 1, 2)], 1)
    other = np.zeros_like(foot)
    cv2.drawContours(other, [o.contour for o in near], -1, 1, thickness=cv2.FILLED,
                     offset=(-int(u0), -int(v0)))
    return bool(cv2.countNonZero(cv2.bitwise_and(foot, other)))
