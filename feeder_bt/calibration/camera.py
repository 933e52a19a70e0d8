"""Camera <-> belt frame: fit the cell's ``CameraCalibration`` from an image of a target.

The model is the one ``feeder_bt.vision.calibration`` uses, a similarity *with reflection*
(the image's v axis runs along the belt)::

    x = ox + s (v cos r - u sin r) = ox + a v - b u
    y = oy + s (v sin r + u cos r) = oy + a u + b v        with a = s cos r, b = s sin r

It is linear in ``(a, b, ox, oy)``, so the least-squares fit is one ``lstsq``. OpenCV's
``estimateAffinePartial2D`` fits rotation + uniform scale + translation *without*
reflection (and robustly, by RANSAC, by default), so it cannot be used as is; a full
affine and a homography are fitted as well, only to tell whether the camera looks tilted
(a homography explaining the points much better than the model can).

The target (a chessboard or a symmetric dot grid) lies flat on the belt at a known pose:
placed against fixtures, or its corners touched by the robot. Its feature points are then
known in the belt frame, and the camera gives them in pixels.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from ..hal.interfaces import Camera, Frame
from ..scenario.model import CameraCalibration
from ..vision.calibration import Calibration
from .common import CalibrationError, Waiter, rms_max

MIN_POINTS = 4
TILT_RATIO = 2.0         # homography rms this many times smaller than the model's ...
TILT_MIN_GAIN_MM = 0.1   # ... and by at least this much: the camera may be tilted


@dataclass(frozen=True)
class Target:
    """A calibration target: ``nx`` x ``ny`` feature points ``pitch_mm`` apart.

    ``chessboard``: the points are the inner corners, so the board has ``nx + 1`` by
    ``ny + 1`` squares. ``dots``: a symmetric grid of dark dots ``dot_mm`` across.
    Board x runs along ``nx``; the board frame's origin is the centre of the points.
    """

    kind: str = "chessboard"
    nx: int = 8
    ny: int = 12
    pitch_mm: float = 40.0
    dot_mm: float = 14.0

    def __post_init__(self) -> None:
        if self.kind not in ("chessboard", "dots"):
            raise CalibrationError(f"target kind must be chessboard or dots, got {self.kind!r}")
        if self.nx < 2 or self.ny < 2:
            raise CalibrationError(f"a target needs at least 2x2 points, got {self.nx}x{self.ny}")
        if not self.pitch_mm > 0:
            raise CalibrationError(f"target pitch_mm must be > 0, got {self.pitch_mm}")

    def points_board(self) -> np.ndarray:
        """``(ny, nx, 2)`` feature points in the board frame (mm)."""
        i = (np.arange(self.nx) - (self.nx - 1) / 2.0) * self.pitch_mm
        j = (np.arange(self.ny) - (self.ny - 1) / 2.0) * self.pitch_mm
        bx, by = np.meshgrid(i, j)
        return np.stack([bx, by], axis=-1)


DEFAULT_TARGETS = {
    "chessboard": Target("chessboard", nx=8, ny=12, pitch_mm=40.0),
    "dots": Target("dots", nx=9, ny=13, pitch_mm=36.0, dot_mm=14.0),
}


@dataclass(frozen=True)
class TargetPose:
    """Where the target lies: its centre in the belt frame (mm) and its x axis's angle
    from the belt's x axis (degrees)."""

    x_mm: float
    y_mm: float
    angle_deg: float = 0.0

    def to_belt(self, pts: np.ndarray) -> np.ndarray:
        r = math.radians(self.angle_deg)
        c, s = math.cos(r), math.sin(r)
        rot = np.array([[c, -s], [s, c]])
        return pts @ rot.T + np.array([self.x_mm, self.y_mm])


def target_points_mm(target: Target, pose: TargetPose) -> np.ndarray:
    """``(ny, nx, 2)`` feature points of a target lying at ``pose``, belt frame (mm)."""
    return pose.to_belt(target.points_board().reshape(-1, 2)).reshape(target.ny, target.nx, 2)


def centred_pose(calibration: CameraCalibration, width_px: int, height_px: int,
                 angle_deg: float = 0.0) -> TargetPose:
    """The pose that centres a target in the camera window as ``calibration`` sees it."""
    c = Calibration(calibration).px_to_mm(np.array([[(width_px - 1) / 2, (height_px - 1) / 2]]))
    return TargetPose(float(c[0, 0]), float(c[0, 1]), angle_deg)


# ------------------------------------------------------------------------------ fitting


@dataclass
class CameraFit:
    """A fitted camera calibration and how well it explains the points."""

    calibration: CameraCalibration
    rms_mm: float
    max_mm: float
    n_points: int
    affine_rms_mm: float
    homography_rms_mm: float
    hint: str | None = None

    def as_dict(self) -> dict:
        c = self.calibration
        d = {"origin_mm": [round(float(c.origin_mm[0]), 4), round(float(c.origin_mm[1]), 4)],
             "mm_per_px": round(float(c.mm_per_px), 7),
             "rotation_deg": round(float(c.rotation_deg), 5),
             "residual_mm": {"rms": round(self.rms_mm, 4), "max": round(self.max_mm, 4)},
             "points": self.n_points,
             "affine_rms_mm": round(self.affine_rms_mm, 4),
             "homography_rms_mm": round(self.homography_rms_mm, 4)}
        if self.hint:
            d["hint"] = self.hint
        return d


def _check_points(px: np.ndarray, mm: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    px = np.asarray(px, dtype=float).reshape(-1, 2)
    mm = np.asarray(mm, dtype=float).reshape(-1, 2)
    if len(px) != len(mm):
        raise CalibrationError(f"{len(px)} pixel points but {len(mm)} mm points: "
                               "they must correspond one to one")
    if len(px) < MIN_POINTS:
        raise CalibrationError(f"need at least {MIN_POINTS} (pixel, mm) correspondences, "
                               f"got {len(px)}")
    if not (np.isfinite(px).all() and np.isfinite(mm).all()):
        raise CalibrationError("a correspondence is not a finite number")
    for name, pts in (("pixel", px), ("mm", mm)):
        sv = np.linalg.svd(pts - pts.mean(axis=0), compute_uv=False)
        if sv[0] <= 0 or sv[1] / sv[0] < 1e-3:
            raise CalibrationError(f"the {name} points are (nearly) on one line: spread them "
                                   "over the window")
    return px, mm


def fit_camera(px: np.ndarray, mm: np.ndarray) -> CameraFit:
    """Least-squares ``CameraCalibration`` from ``(N, 2)`` pixel ``(u, v)`` and belt ``(x, y)``
    mm correspondences, with residuals and a tilt hint."""
    px, mm = _check_points(px, mm)
    n = len(px)
    u, v = px[:, 0], px[:, 1]
    one, zero = np.ones(n), np.zeros(n)
    a_mat = np.vstack([np.column_stack([v, -u, one, zero]),
                       np.column_stack([u, v, zero, one])])
    rhs = np.concatenate([mm[:, 0], mm[:, 1]])
    (a, b, ox, oy), *_ = np.linalg.lstsq(a_mat, rhs, rcond=None)
    s = math.hypot(a, b)
    cal = CameraCalibration(origin_mm=(float(ox), float(oy)), mm_per_px=float(s),
                            rotation_deg=math.degrees(math.atan2(b, a)))
    rms, mx = rms_max(Calibration(cal).px_to_mm(px) - mm)
    aff_rms = _affine_rms(px, mm)
    hom_rms = _homography_rms(px, mm)
    hint = None
    if rms > TILT_MIN_GAIN_MM and hom_rms * TILT_RATIO < rms and rms - hom_rms > TILT_MIN_GAIN_MM:
        hint = (f"a homography fits much better (rms {hom_rms:.2f} mm against {rms:.2f} mm): "
                "the camera is probably tilted; square it to the belt")
    elif rms > TILT_MIN_GAIN_MM and aff_rms * TILT_RATIO < rms:
        hint = (f"a full affine fits much better (rms {aff_rms:.2f} mm against {rms:.2f} mm): "
                "the pixels are not square or the camera is tilted")
    return CameraFit(cal, rms, mx, n, aff_rms, hom_rms, hint)


def _affine_rms(px: np.ndarray, mm: np.ndarray) -> float:
    a_mat = np.column_stack([px, np.ones(len(px))])
    coef, *_ = np.linalg.lstsq(a_mat, mm, rcond=None)
    return rms_max(a_mat @ coef - mm)[0]


def _homography_rms(px: np.ndarray, mm: np.ndarray) -> float:
    h, _ = cv2.findHomography(px, mm, 0)           # method 0: least squares, all points
    if h is None:
        return math.inf
    return rms_max(cv2.perspectiveTransform(px.reshape(-1, 1, 2), h).reshape(-1, 2) - mm)[0]


def window_error_mm(a: CameraCalibration, b: CameraCalibration, width_px: int,
                    height_px: int) -> float:
    """Largest distance (mm) between where ``a`` and ``b`` put a pixel of the window.

    Both maps are affine, so the largest difference is at a corner."""
    corners = np.array([[0, 0], [width_px - 1, 0], [0, height_px - 1],
                        [width_px - 1, height_px - 1]], dtype=float)
    d = Calibration(a).px_to_mm(corners) - Calibration(b).px_to_mm(corners)
    return float(np.linalg.norm(d, axis=1).max())


# ------------------------------------------------------------------------------ detection


def detect_target(image: np.ndarray, target: Target) -> np.ndarray:
    """Feature points of ``target`` in ``image``: ``(ny, nx, 2)`` pixels, in OpenCV's order
    (row by row; which corner comes first is up to OpenCV — see ``match_order``)."""
    img = np.asarray(image)
    if img.ndim == 3:
        img = cv2.cvtColor(img, cv2.COLOR_BGR2GRAY)
    if img.dtype != np.uint8 or img.ndim != 2 or img.size == 0:
        raise CalibrationError("the camera image must be an 8-bit grey or colour image")
    size = (target.nx, target.ny)                  # (points per row, points per column)
    if target.kind == "chessboard":
        flags = (cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE
                 | cv2.CALIB_CB_FAST_CHECK)          # FAST_CHECK: give up quickly on no board
        found, pts = cv2.findChessboardCorners(img, size, flags=flags)
        if found:
            criteria = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 50, 1e-3)
            pts = cv2.cornerSubPix(img, pts, (5, 5), (-1, -1), criteria)
        what = f"chessboard of {target.nx}x{target.ny} inner corners"
    else:
        found, pts = cv2.findCirclesGrid(img, size, flags=cv2.CALIB_CB_SYMMETRIC_GRID)
        what = f"{target.nx}x{target.ny} grid of dots"
    if not found or pts is None:
        raise CalibrationError(f"no {what} found in the image: is the whole target in view, "
                               "flat, lit and of that size?")
    return np.asarray(pts, dtype=float).reshape(target.ny, target.nx, 2)


def match_order(detected_px: np.ndarray, expected_px: np.ndarray, pitch_px: float) -> np.ndarray:
    """Reorder detected grid points to correspond to the expected ones.

    OpenCV may return a grid starting from any corner (and, for a square grid, transposed);
    the expected pixels (the known target pose through the cell's present calibration)
    decide which. The present calibration may be off by anything under half a pitch.
    """
    candidates = [detected_px[::sj, ::si] for sj in (1, -1) for si in (1, -1)]
    if detected_px.shape[0] == detected_px.shape[1]:
        candidates += [c.transpose(1, 0, 2) for c in candidates]
    errs = [float(np.linalg.norm(c - expected_px, axis=-1).mean()) for c in candidates]
    best = int(np.argmin(errs))
    if errs[best] > 0.5 * pitch_px:
        raise CalibrationError(f"the target was found {errs[best]:.0f} px on average from where "
                               "the cell's present calibration expects it (more than half a "
                               "pitch): check the target pose, or the calibration is far off")
    return candidates[best]


def correspondences(image: np.ndarray, target: Target, pose: TargetPose,
                    nominal: CameraCalibration) -> tuple[np.ndarray, np.ndarray]:
    """``(pixels, mm)`` of the target's points in ``image``, each ``(N, 2)``."""
    mm = target_points_mm(target, pose)
    expected = Calibration(nominal).mm_to_px(mm.reshape(-1, 2)).reshape(mm.shape)
    found = detect_target(image, target)
    px = match_order(found, expected, target.pitch_mm / nominal.mm_per_px)
    return px.reshape(-1, 2), mm.reshape(-1, 2)


def calibrate_camera_image(image: np.ndarray, target: Target, pose: TargetPose,
                           nominal: CameraCalibration) -> CameraFit:
    """Fit the camera from one image of ``target`` lying at ``pose``."""
    px, mm = correspondences(image, target, pose, nominal)
    return fit_camera(px, mm)


def camera_procedure(camera: Camera, wait: Waiter, target: Target, pose: TargetPose,
                     nominal: CameraCalibration) -> CameraFit:
    """The guided procedure: with the target lying at ``pose`` on the belt (belt stopped,
    backlight on), grab a frame and fit the calibration from its pixels."""
    frame: Frame = wait(camera.grab())
    return calibrate_camera_image(frame.image, target, pose, nominal)
