"""The camera's lens from several views of a target, and the belt plane through it.

``calibrate_views`` estimates the full pinhole-and-lens model of OpenCV
(``cv2.calibrateCameraExtended``): focal lengths ``fx, fy`` and principal point ``cx, cy``
in pixels and the distortion ``k1, k2, p1, p2, k3`` (the rational model ``k4..k6`` as well
when asked, or when ``model="auto"`` and it explains the views much better: a wide lens),
with each view's reprojection error and the model's uncertainty (one standard deviation of
each intrinsic, from the Jacobian at the solution). A view whose error is far above the
others' (``OUTLIER_FACTOR`` times their median and over ``OUTLIER_PX``) is dropped, the worst
first, the model refitted, and the report says so. Nothing is held fixed but the skew (0)
and ``k3`` (0) with fewer than ``FULL_VIEWS`` views; ``k3``, then ``k2``, are held at 0 too
when freeing them lowers the rms by no more than ``K3_GAIN``: a higher-order term the
views do not need bends the model wildly where no view reached (the window's corners).

``fit_belt_plane`` maps the belt: the pixels of the target lying at a known pose, undistorted
by the model (``cv2.undistortPoints``, back to pixel units), to belt millimetres by a
homography (``cv2.findHomography``, least squares over all points), so a camera that is
not square to the belt is right. One view (no lens model) still fits that homography to
the raw pixels.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import cv2
import numpy as np

from feeder_bt.calibration.camera import fit_camera
from feeder_bt.calibration.procedure import CalibrationError, rms_max
from feeder_bt.calibration.targets import Target, detect_points
from feeder_bt.core.model import CameraCalibration

MIN_VIEWS = 3
FULL_VIEWS = 5            # from this many views k3 is estimated too
OUTLIER_FACTOR = 3.0
OUTLIER_PX = 0.5
RATIONAL_GAIN = 0.75      # auto: the rational model when its rms is under this share
K3_GAIN = 1.02            # k3 is kept only if it lowers the rms by more than 2 %


@dataclass
class View:
    """One image's target points: ``px`` (N, 2), their index into the board's points and
    (``find_views`` sets it) those points on the board, mm (N, 2): a view carries its own
    board, so views of different boards held in front of one camera calibrate it together."""

    name: str
    px: np.ndarray
    index: np.ndarray
    board: np.ndarray | None = None


@dataclass
class CameraModel:
    """A fitted camera: intrinsics, distortion, errors and uncertainty."""

    fx: float
    fy: float
    cx: float
    cy: float
    dist: list[float]
    rms_px: float
    size: tuple[int, int]
    per_view: dict[str, float]
    used: list[str]
    dropped: list[tuple[str, str]] = field(default_factory=list)
    std: dict[str, float] = field(default_factory=dict)
    rational: bool = False

    @property
    def matrix(self) -> np.ndarray:
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    def as_dict(self) -> dict:
        return {"fx": round(self.fx, 4), "fy": round(self.fy, 4), "cx": round(self.cx, 4),
                "cy": round(self.cy, 4), "dist": [round(float(d), 8) for d in self.dist],
                "model": "rational" if self.rational else "standard",
                "rms_px": round(self.rms_px, 5),
                "std": {k: round(v, 6) for k, v in self.std.items()},
                "per_view_rms_px": {k: round(v, 4) for k, v in self.per_view.items()}}


def find_views(images: Sequence[tuple[str, np.ndarray]], target: Target,
               px_per_mm: float | None = None) -> tuple[list[View], list[tuple[str, str]]]:
    """The target in each named image: the views found and, for the rest, why not (not
    found, or points that do not fit the board: ``targets.detect_points``)."""
    views, rejected = [], []
    size = None
    for name, image in images:
        shape = np.asarray(image).shape[:2]
        if size is None:
            size = shape
        elif shape != size:
            rejected.append((name, f"{shape[1]}x{shape[0]} px, the first view "
                                   f"{size[1]}x{size[0]}: another camera?"))
            continue
        try:
            px, index = detect_points(image, target, px_per_mm)
        except CalibrationError as e:
            rejected.append((name, str(e)))
            continue
        views.append(View(name, px, index, target.points_board().reshape(-1, 2)[index]))
    return views, rejected


_STD_NAMES = ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6")


def _fit(views: list[View], target: Target, size: tuple[int, int], rational: bool,
         fixed: int = 0):
    """One ``calibrateCameraExtended``; ``fixed``: 1 holds k3 at 0, 2 k2 and k3."""
    board = target.points_board().reshape(-1, 2)
    obj = [np.column_stack([board[v.index] if v.board is None else v.board,
                            np.zeros(len(v.index))]).astype(np.float32) for v in views]
    img = [v.px.astype(np.float32).reshape(-1, 1, 2) for v in views]
    flags = cv2.CALIB_RATIONAL_MODEL if rational else 0
    if len(views) < FULL_VIEWS or fixed >= 1:
        flags |= cv2.CALIB_FIX_K3
    if fixed >= 2:
        flags |= cv2.CALIB_FIX_K2
    crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-12)
    try:
        rms, k, dist, _, _, std, _, per_view = cv2.calibrateCameraExtended(
            obj, img, size, None, None, flags=flags, criteria=crit)
    except cv2.error as e:
        msg = str(e).strip().splitlines()[-1][:160]
        raise CalibrationError(f"OpenCV could not calibrate from these views ({msg}): "
                               "give views of the target turned and tilted") from None
    n = 8 if rational else 5                   # OpenCV may hand back all 14 (zeros)
    return float(rms), k, dist.ravel()[:n], std.ravel(), per_view.ravel()


def calibrate_views(views: list[View], target: Target, size: tuple[int, int],
                    model: str = "auto") -> CameraModel:
    """The full camera model from ``views`` (``size``: image width, height); ``model``:
    ``standard`` (k1, k2, p1, p2, k3), ``rational`` (and k4..k6) or ``auto``. A view that
    carries its own board points (``View.board``) is fitted to them, ``target``'s otherwise."""
    if model not in ("auto", "standard", "rational"):
        raise CalibrationError(f"lens model must be auto, standard or rational, got {model!r}")
    views = list(views)
    dropped: list[tuple[str, str]] = []
    if len(views) < MIN_VIEWS:
        raise CalibrationError(f"the lens needs at least {MIN_VIEWS} views of the target, "
                               f"{len(views)} usable")
    while True:
        rational = model == "rational"
        rms, k, dist, std, per = _fit(views, target, size, rational)
        if not rational:
            # a term the views do not need would only bend the model where no view reached
            if len(views) >= FULL_VIEWS:
                r3 = _fit(views, target, size, False, fixed=1)
                if r3[0] <= K3_GAIN * rms:
                    rms, k, dist, std, per = r3
            if not dist[4]:
                r2 = _fit(views, target, size, False, fixed=2)
                if r2[0] <= K3_GAIN * rms:
                    rms, k, dist, std, per = r2
        if model == "auto" and len(views) >= FULL_VIEWS + 3:
            r2 = _fit(views, target, size, True)
            if r2[0] < RATIONAL_GAIN * rms:
                rational = True
                rms, k, dist, std, per = r2
        med = float(np.median(per))
        worst = int(np.argmax(per))
        if (len(views) > MIN_VIEWS and per[worst] > OUTLIER_FACTOR * med
                and per[worst] > OUTLIER_PX):
            dropped.append((views[worst].name,
                            f"reprojection rms {per[worst]:.2f} px, {per[worst] / med:.1f} times "
                            f"the median view's {med:.2f} px"))
            del views[worst]
            continue
        break
    names = _STD_NAMES[:4 + len(dist)]
    return CameraModel(fx=float(k[0, 0]), fy=float(k[1, 1]), cx=float(k[0, 2]),
                       cy=float(k[1, 2]), dist=[float(d) for d in dist], rms_px=rms,
                       size=size, per_view={v.name: float(e) for v, e in zip(views, per,
                                                                              strict=True)},
                       used=[v.name for v in views], dropped=dropped,
                       std={n: float(s) for n, s in zip(names, std, strict=False)},
                       rational=rational)


@dataclass
class BeltPlane:
    """Undistorted pixels -> belt mm: the homography and its residual."""

    calibration: CameraCalibration
    rms_mm: float
    max_mm: float
    n_points: int
    similarity_rms_mm: float


PRIOR_KEEP = 1.25          # a one-view fit keeps the present tilt unless a new one fits ...
PRIOR_KEEP_MM = 0.02       # ... this much better (ratio, and mm)


def fit_belt_plane(px: np.ndarray, mm: np.ndarray, lens: CameraModel | None = None,
                   intrinsics: tuple[float, float, float, float] | None = None,
                   dist: Sequence[float] = (), prior: Sequence[float] | None = None
                   ) -> BeltPlane:
    """The belt plane from one view of the target at a known pose: ``px`` (N, 2) pixels and
    ``mm`` (N, 2) belt points; the lens from ``lens`` (or ``intrinsics``/``dist``, a lens
    calibrated before), none: the raw pixels.

    ``prior`` (the present calibration's homography, same lens): the camera has probably
    only moved or turned on its mount, so the present homography moved by a belt-frame
    similarity is tried too and kept unless a fresh homography fits clearly better
    (``PRIOR_KEEP``): a small target fixes the 8 numbers of a homography poorly towards
    the window's corners, a similarity's 4 well."""
    px = np.asarray(px, dtype=float).reshape(-1, 2)
    mm = np.asarray(mm, dtype=float).reshape(-1, 2)
    if lens is not None:
        intrinsics = (lens.fx, lens.fy, lens.cx, lens.cy)
        dist = lens.dist
    base = CameraCalibration(intrinsics=intrinsics if any(dist) else None,
                             dist=[float(d) for d in dist] if intrinsics else [])
    from feeder_bt.vision.pixels import Calibration

    und = Calibration(base).undistort(px)
    sim = fit_camera(und, mm)                     # checks the points; the nearest similarity
    h, _ = cv2.findHomography(und, mm, 0)
    if h is None:
        raise CalibrationError("no homography fits the target's points: are they on a line?")
    h = h / h[2, 2]
    res = cv2.perspectiveTransform(und.reshape(-1, 1, 2), h).reshape(-1, 2) - mm
    rms, mx = rms_max(res)
    if prior is not None:
        h0 = np.array(prior, dtype=float).reshape(3, 3)
        q = cv2.perspectiveTransform(und.reshape(-1, 1, 2), h0).reshape(-1, 2)
        a = _similarity(q, mm)
        hp = a @ h0
        hp /= hp[2, 2]
        res_p = cv2.perspectiveTransform(und.reshape(-1, 1, 2), hp).reshape(-1, 2) - mm
        rms_p, mx_p = rms_max(res_p)
        if rms_p <= max(PRIOR_KEEP * rms, rms + PRIOR_KEEP_MM):
            h, rms, mx = hp, rms_p, mx_p
    s = sim.calibration
    cal = CameraCalibration(origin_mm=s.origin_mm, mm_per_px=s.mm_per_px,
                            rotation_deg=s.rotation_deg, intrinsics=base.intrinsics,
                            dist=list(base.dist), homography=[float(v) for v in h.ravel()])
    return BeltPlane(cal, rms, mx, len(px), sim.rms_mm)


def _similarity(src: np.ndarray, dst: np.ndarray) -> np.ndarray:
    """Least-squares rotation + scale + offset (no reflection) taking ``src`` to ``dst``, 3x3."""
    n = len(src)
    x, y = src[:, 0], src[:, 1]
    one, zero = np.ones(n), np.zeros(n)
    a_mat = np.vstack([np.column_stack([x, -y, one, zero]), np.column_stack([y, x, zero, one])])
    (a, b, tx, ty), *_ = np.linalg.lstsq(a_mat, np.concatenate([dst[:, 0], dst[:, 1]]),
                                         rcond=None)
    return np.array([[a, -b, tx], [b, a, ty], [0.0, 0.0, 1.0]])


def nearest_similarity_scale(cal: CameraCalibration) -> float:
    """mm per px of a calibration's homography at the principal point (or its similarity's)."""
    if cal.homography is None:
        return cal.mm_per_px
    h = np.array(cal.homography, dtype=float).reshape(3, 3)
    c = np.array(cal.intrinsics[2:] if cal.intrinsics else (0.0, 0.0))
    q = h @ np.array([c[0], c[1], 1.0])
    j = (h[:2, :2] * q[2] - np.outer(q[:2], h[2, :2])) / q[2] ** 2
    return math.sqrt(abs(np.linalg.det(j)))
