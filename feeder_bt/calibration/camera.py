"""Camera <-> belt frame: fit the cell's ``CameraCalibration`` from an image of a target.

The model is the one ``feeder_bt.vision.pixels`` uses, a similarity *with reflection*
(the image's v axis runs along the belt)::

    x = ox + s (v cos r - u sin r) = ox + a v - b u
    y = oy + s (v sin r + u cos r) = oy + a u + b v        with a = s cos r, b = s sin r

It is linear in ``(a, b, ox, oy)``, so the least-squares fit is one ``lstsq``. OpenCV's
``estimateAffinePartial2D`` fits rotation + uniform scale + translation *without*
reflection (and robustly, by RANSAC, by default), so it cannot be used as is; a full
affine and a homography are fitted as well, only to tell whether the camera looks tilted
(a homography explaining the points much better than the model can).

The target (any of ``targets.KINDS``: chessboards, circle grids, ChArUco boards) lies flat
on the belt at a known pose: placed against fixtures, or its corners touched by the robot.
Its feature points are then known in the belt frame, and the camera gives them in pixels.
Which detected point is which comes from the board itself (ChArUco markers, an asymmetric
grid) or, for a symmetric grid, from the cell's present calibration (within half a pitch)
or, for a first calibration (``prior=False``), from the board's colours and handedness
(``order_grid``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from feeder_bt.calibration.procedure import CalibrationError, rms_max
from feeder_bt.calibration.targets import DEFAULT_TARGETS, Target, detect_points
from feeder_bt.core.model import CameraCalibration
from feeder_bt.vision.pixels import Calibration

__all__ = ["DEFAULT_TARGETS", "CameraFit", "Target", "TargetPose",
           "centred_pose", "correspondences", "detect_target",
           "fit_camera", "match_order", "order_grid", "target_points_mm", "window_error_mm"]

MIN_POINTS = 4
TILT_RATIO = 2.0         # homography rms this many times smaller than the model's ...
TILT_MIN_GAIN_MM = 0.1   # ... and by at least this much: the camera may be tilted


@dataclass(frozen=True)
class TargetPose:
    """Where the target lies, face up: its centre in the belt frame (mm) and its x axis's
    angle from the belt's x axis (degrees).

    The belt frame, seen from above, is a mirror image of the board's printed frame (x
    right, y down, as a camera image), as it is of the camera's: so a board's y goes to
    the belt mirrored, and the camera sees the board as printed (ArUco markers and
    asymmetric grids read only that way)."""

    x_mm: float
    y_mm: float
    angle_deg: float = 0.0

    def to_belt(self, pts: np.ndarray) -> np.ndarray:
        r = math.radians(self.angle_deg)
        c, s = math.cos(r), math.sin(r)
        rot = np.array([[c, s], [s, -c]])           # turn after mirroring the board's y
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
    similarity_rms_mm: float | None = None   # a belt-plane fit: what a similarity leaves

    def as_dict(self) -> dict:
        d = calibration_values(self.calibration)
        d.update({
             "residual_mm": {"rms": round(self.rms_mm, 4), "max": round(self.max_mm, 4)},
             "points": self.n_points,
             "affine_rms_mm": round(self.affine_rms_mm, 4),
             "homography_rms_mm": round(self.homography_rms_mm, 4)})
        if self.similarity_rms_mm is not None:
            d["similarity_rms_mm"] = round(self.similarity_rms_mm, 4)
        if self.hint:
            d["hint"] = self.hint
        return d


def calibration_values(c: CameraCalibration) -> dict:
    """A ``CameraCalibration`` as the calibration file's keys (``calibration.files``)."""
    d: dict = {"origin_mm": [round(float(c.origin_mm[0]), 5), round(float(c.origin_mm[1]), 5)],
               "mm_per_px": round(float(c.mm_per_px), 8),
               "rotation_deg": round(float(c.rotation_deg), 6)}
    if c.intrinsics is not None:
        d["intrinsics"] = [round(float(v), 5) for v in c.intrinsics]
        d["dist"] = [float(f"{v:.9g}") for v in c.dist]
    if c.homography is not None:
        d["homography"] = [float(f"{v:.12g}") for v in c.homography]
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

    Two similarities differ most at a corner; with a lens or a homography the window is
    sampled (17 x 13 pixels, corners included)."""
    u, v = np.meshgrid(np.linspace(0, width_px - 1, 17), np.linspace(0, height_px - 1, 13))
    grid = np.column_stack([u.ravel(), v.ravel()])
    d = Calibration(a).px_to_mm(grid) - Calibration(b).px_to_mm(grid)
    return float(np.linalg.norm(d, axis=1).max())


# ------------------------------------------------------------------------------ detection


def detect_target(image: np.ndarray, target: Target) -> np.ndarray:
    """Feature points of a grid ``target`` in ``image``: ``(ny, nx, 2)`` pixels, in OpenCV's
    order (row by row; which corner comes first is up to OpenCV — see ``order_grid``)."""
    px, _ = detect_points(image, target)
    if len(px) != target.nx * target.ny:
        raise CalibrationError(f"found {len(px)} of the {target.nx * target.ny} points of the "
                               f"{target.describe()}")
    return px.reshape(target.ny, target.nx, 2)


def match_order(detected_px: np.ndarray, expected_px: np.ndarray, pitch_px: float) -> np.ndarray:
    """Reorder detected grid points to correspond to the expected ones.

    OpenCV may return a grid starting from any corner (and, for a square grid, transposed);
    the expected pixels (the known target pose through the cell's present calibration)
    decide which. The present calibration may be off by anything under half a pitch.
    """
    candidates = _readings(detected_px)
    errs = [float(np.linalg.norm(c - expected_px, axis=-1).mean()) for c in candidates]
    best = int(np.argmin(errs))
    if errs[best] > 0.5 * pitch_px:
        raise CalibrationError(f"the target was found {errs[best]:.0f} px on average from where "
                               "the cell's present calibration expects it (more than half a "
                               "pitch): check the target pose, or, for a first calibration, "
                               "give --no-prior (the stated pose is then trusted)")
    return candidates[best]


def _readings(grid: np.ndarray) -> list[np.ndarray]:
    """The ways a symmetric grid's detected points may be read: from each corner, and
    transposed when it is square."""
    out = [grid[::sj, ::si] for sj in (1, -1) for si in (1, -1)]
    if grid.shape[0] == grid.shape[1]:
        out += [c.transpose(1, 0, 2) for c in out]
    return out


def order_grid(image: np.ndarray, grid: np.ndarray, target: Target, mm: np.ndarray,
               rotation_deg: float) -> tuple[np.ndarray, str | None]:
    """A first calibration's reading of a symmetric grid, without a prior position.

    A reading that mirrors the board cannot be fitted by the camera model (which has one
    handedness), so the fit's residual rules those out. Of the rest, for a chessboard, the
    one that puts a dark square at the board's (-x, -y) corner; if that leaves several
    (a board that looks the same turned half round, or a circle grid), the one whose
    rotation is nearest ``rotation_deg`` (the present calibration's, which only needs to be
    right to within a quarter turn), with a note saying so.
    """
    flat = mm.reshape(-1, 2)
    fits = []
    for c in _readings(grid):
        f = fit_camera(c.reshape(-1, 2), flat)
        fits.append((c, f))
    best_rms = min(f.rms_mm for _, f in fits)
    ok = [(c, f) for c, f in fits if f.rms_mm <= max(4 * best_rms, 0.05 * target.pitch_mm)]
    note = None
    if target.kind == "chessboard" and len(ok) > 1:
        coloured = [(c, f) for c, f in ok if _dark_corner(image, c)]
        if coloured:
            ok = coloured
    if len(ok) > 1:
        note = (f"the {target.describe()} reads the same turned round: its reading was "
                f"chosen by the present calibration's rotation ({rotation_deg:g} deg)")

        def turn(item) -> float:
            d = (item[1].calibration.rotation_deg - rotation_deg + 180.0) % 360.0 - 180.0
            return abs(d)
        ok.sort(key=turn)
    return ok[0][0], note


def _dark_corner(image: np.ndarray, grid: np.ndarray) -> bool:
    """Whether the square beyond a grid reading's first corner (the board's (-x, -y)
    corner square) is darker than its neighbour along the first row."""
    img = np.asarray(image)
    if img.ndim == 3:
        img = cv2.cvtColor(img, cv2.COLOR_BGR2GRAY)
    p0, ex, ey = grid[0, 0], grid[0, 1] - grid[0, 0], grid[1, 0] - grid[0, 0]

    def grey(pt: np.ndarray) -> float:
        u, v = int(round(pt[0])), int(round(pt[1]))
        h, w = img.shape
        if not (1 <= u < w - 1 and 1 <= v < h - 1):
            return math.nan
        return float(img[v - 1:v + 2, u - 1:u + 2].mean())

    dark, light = grey(p0 - (ex + ey) / 2), grey(p0 + (ex - ey) / 2)
    return not math.isnan(dark) and not math.isnan(light) and dark < light


def correspondences(image: np.ndarray, target: Target, pose: TargetPose,
                    nominal: CameraCalibration, prior: bool = True
                    ) -> tuple[np.ndarray, np.ndarray, str | None]:
    """``(pixels, mm, note)`` of the target's points in ``image``, each ``(N, 2)``; see the
    module docstring for how points are identified (``prior``: the present calibration is
    close enough to tell a symmetric grid's corners apart)."""
    mm = target_points_mm(target, pose)
    px, index = detect_points(image, target)
    if target.kind == "charuco":
        return px, mm.reshape(-1, 2)[index], None
    if len(px) != target.nx * target.ny:
        raise CalibrationError(f"found {len(px)} of the {target.nx * target.ny} points of the "
                               f"{target.describe()}")
    grid = px.reshape(target.ny, target.nx, 2)
    if target.kind == "acircles":                # one reading fits: the best-fitting one
        ordered, _ = order_grid(image, grid, target, mm, nominal.rotation_deg)
        return ordered.reshape(-1, 2), mm.reshape(-1, 2), None
    if prior:
        expected = Calibration(nominal).mm_to_px(mm.reshape(-1, 2)).reshape(mm.shape)
        ordered = match_order(grid, expected, target.pitch_mm / nominal.mm_per_px)
        return ordered.reshape(-1, 2), mm.reshape(-1, 2), None
    ordered, note = order_grid(image, grid, target, mm, nominal.rotation_deg)
    return ordered.reshape(-1, 2), mm.reshape(-1, 2), note
