"""Lens distortion from several views of a calibration target (``cv2.calibrateCamera``).

The cell's camera model (``feeder_bt.vision.pixels``) has no distortion: it maps
pixels to the belt by a similarity. This estimates how far the lens bends the image, so
the user knows whether that model is good enough: the views (the target anywhere in the
window, turned, at least three) give radial distortion ``k1`` (``k2`` too with
``k2=True``: it needs views reaching the window's corners); the report is the largest
shift distortion causes over the part of the window the views covered (their points'
bounding box: beyond it the polynomial is a guess), in pixels. The focal length
cannot be told from views of a flat target square to the camera, so it is held at the
image width (distortion is reported as a shift in pixels, which does not depend on it).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from feeder_bt.calibration.procedure import CalibrationError
from feeder_bt.calibration.targets import Target, detect_points

MIN_VIEWS = 3


@dataclass
class LensFit:
    k1: float
    k2: float
    rms_px: float               # reprojection rms over all views
    max_shift_px: float         # largest distortion shift over the views' points' box
    views: int
    points: int

    def as_dict(self) -> dict:
        return {"k1": round(self.k1, 6), "k2": round(self.k2, 6),
                "reprojection_rms_px": round(self.rms_px, 4),
                "max_shift_px": round(self.max_shift_px, 3), "views": self.views}


def fit_lens(images: list[np.ndarray], target: Target, k2: bool = False) -> LensFit:
    """Radial distortion from ``images`` of ``target`` (each wholly or, for ChArUco, partly
    in view). A grid's reading does not matter here: each view gets its own pose."""
    if len(images) < MIN_VIEWS:
        raise CalibrationError(f"lens distortion needs at least {MIN_VIEWS} views of the "
                               f"target (--image repeated), got {len(images)}")
    board = target.points_board().reshape(-1, 2)
    obj, img_pts = [], []
    h, w = images[0].shape[:2]
    for i, image in enumerate(images):
        if image.shape[:2] != (h, w):
            raise CalibrationError(f"view {i + 1} is {image.shape[1]}x{image.shape[0]} px, "
                                   f"the first {w}x{h}: all views must come from one camera")
        px, index = detect_points(image, target)
        obj.append(np.column_stack([board[index], np.zeros(len(index))]).astype(np.float32))
        img_pts.append(px.astype(np.float32).reshape(-1, 1, 2))
    f = float(w)
    k = np.array([[f, 0, (w - 1) / 2], [0, f, (h - 1) / 2], [0, 0, 1]])
    flags = (cv2.CALIB_USE_INTRINSIC_GUESS | cv2.CALIB_FIX_FOCAL_LENGTH
             | cv2.CALIB_FIX_PRINCIPAL_POINT | cv2.CALIB_FIX_ASPECT_RATIO
             | cv2.CALIB_ZERO_TANGENT_DIST | cv2.CALIB_FIX_K3
             | (0 if k2 else cv2.CALIB_FIX_K2))
    rms, k, dist, _, _ = cv2.calibrateCamera(obj, img_pts, (w, h), k, np.zeros(5),
                                             flags=flags)
    seen = np.concatenate(img_pts).reshape(-1, 2)
    (u0, v0), (u1, v1) = seen.min(axis=0), seen.max(axis=0)
    u, v = np.meshgrid(np.linspace(u0, u1, 9), np.linspace(v0, v1, 7))
    grid = np.column_stack([u.ravel(), v.ravel()]).astype(np.float64).reshape(-1, 1, 2)
    undist = cv2.undistortPoints(grid, k, dist, P=k)
    shift = float(np.linalg.norm((undist - grid).reshape(-1, 2), axis=1).max())
    return LensFit(k1=float(dist.ravel()[0]), k2=float(dist.ravel()[1]), rms_px=float(rms),
                   max_shift_px=shift, views=len(images),
                   points=sum(len(p) for p in img_pts))
