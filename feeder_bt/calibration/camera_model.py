"""``feeder calibrate camera`` from images: the lens, the belt plane, the verdict.

``calibrate_camera_views`` takes the named images of the target (the first lying on the
belt at the stated pose; any others anywhere, turned and tilted, for the lens), finds the
target in each (``intrinsics.find_views``: a view that is not found or whose points do not
fit the board is rejected, with its reason), fits the lens from three views or more
(``intrinsics.calibrate_views``), and the belt plane from the first view through that lens
(``intrinsics.fit_belt_plane``; one view: the raw pixels, or the lens the cell was
calibrated with before). ``CameraResult.refusal`` says, in one line naming the worst views,
why the result must not be used: a reprojection or belt residual over the cell's limits
(``camera.target.max_rms_px``, ``max_belt_mm``).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from feeder_bt.calibration.camera import (
    CameraFit,
    TargetPose,
    _affine_rms,
    calibration_values,
    correspondences,
)
from feeder_bt.calibration.intrinsics import (
    MIN_VIEWS,
    BeltPlane,
    CameraModel,
    calibrate_views,
    find_views,
    fit_belt_plane,
)
from feeder_bt.calibration.procedure import CalibrationError, Waiter
from feeder_bt.calibration.targets import Target
from feeder_bt.core.model import CameraCalibration
from feeder_bt.hal.interfaces import Camera, Frame
from feeder_bt.vision.pixels import Calibration

DEFAULT_MAX_RMS_PX = 1.0       # reprojection rms of the lens model over all views
DEFAULT_MAX_BELT_MM = 0.3      # rms of the belt plane over the target's points


@dataclass
class CameraResult:
    """What a camera calibration found and how well."""

    calibration: CameraCalibration
    belt: BeltPlane
    lens: CameraModel | None
    views_rejected: list[tuple[str, str]] = field(default_factory=list)
    note: str | None = None

    @property
    def views_used(self) -> list[str]:
        return self.lens.used if self.lens is not None else [self.first]

    first: str = ""

    def refusal(self, max_rms_px: float = DEFAULT_MAX_RMS_PX,
                max_belt_mm: float = DEFAULT_MAX_BELT_MM) -> str | None:
        """Why this calibration must not be written, in one line, or None."""
        why = []
        if self.lens is not None and self.lens.rms_px > max_rms_px:
            worst = sorted(self.lens.per_view.items(), key=lambda kv: -kv[1])[:3]
            names = ", ".join(f"{n} {e:.2f} px" for n, e in worst)
            why.append(f"reprojection rms {self.lens.rms_px:.3f} px over the limit "
                       f"{max_rms_px:g} px (worst views: {names})")
        if self.belt.rms_mm > max_belt_mm:
            why.append(f"belt plane rms {self.belt.rms_mm:.3f} mm over the limit "
                       f"{max_belt_mm:g} mm (view {self.first}: is the target flat and "
                       "where --pose says?)")
        return "; ".join(why) or None

    def as_dict(self) -> dict:
        c = self.calibration
        d: dict = {}
        if self.lens is not None:
            d.update(self.lens.as_dict())
        else:
            fx, fy, cx, cy = c.intrinsics or (None, None, None, None)
            d.update({"fx": fx, "fy": fy, "cx": cx, "cy": cy, "dist": list(c.dist),
                      "rms_px": None})
        d["views_used"] = self.views_used
        d["views_rejected"] = [{"view": n, "reason": r} for n, r in self.views_rejected]
        d["belt_rms_mm"] = round(self.belt.rms_mm, 5)
        d["belt_max_mm"] = round(self.belt.max_mm, 5)
        d["belt_points"] = self.belt.n_points
        d["similarity_rms_mm"] = round(self.belt.similarity_rms_mm, 5)
        d["calibration"] = calibration_values(c)
        if self.note:
            d["note"] = self.note
        return d




def calibrate_camera_views(images: Sequence[tuple[str, np.ndarray]], target: Target,
                           pose, nominal: CameraCalibration, prior: bool = True,
                           model: str = "auto") -> CameraResult:
    """The camera from named images (see the module docstring); ``nominal``: the cell's
    present calibration (tells a symmetric grid's reading with ``prior``, gives the
    expected dot size, and its lens is kept when one view cannot fit one)."""
    if not images:
        raise CalibrationError("no image of the target")
    px_per_mm = 1.0 / nominal.mm_per_px if nominal.mm_per_px > 0 else None
    first_name, first = images[0]
    # the belt view: its points in the belt frame (its reading decided as before)
    try:
        px, mm, note = correspondences(first, target, pose, nominal, prior)
    except CalibrationError as e:
        raise CalibrationError(f"{first_name} (the view on the belt): {e}") from None
    lens = None
    rejected: list[tuple[str, str]] = []
    if len(images) > 1:
        views, rejected = find_views(images, target, px_per_mm)
        if len(views) < MIN_VIEWS:
            why = "; ".join(f"{n}: {r}" for n, r in rejected[:2])
            raise CalibrationError(f"the lens needs at least {MIN_VIEWS} views of the target, "
                                   f"{len(views)} of {len(images)} usable"
                                   + (f" ({why})" if why else ""))
        h, w = np.asarray(first).shape[:2]
        lens = calibrate_views(views, target, (w, h), model)
        rejected = rejected + lens.dropped
        belt = fit_belt_plane(px, mm, lens)   # a new lens: the old homography no prior
    else:
        belt = fit_belt_plane(px, mm, None, nominal.intrinsics, nominal.dist,
                              prior=nominal.homography)
    return CameraResult(belt.calibration, belt, lens, rejected, note, first=first_name)


def calibrate_camera_image(image: np.ndarray, target: Target, pose: TargetPose,
                           nominal: CameraCalibration, prior: bool = True) -> CameraFit:
    """Fit the belt plane from one image of ``target`` lying at ``pose`` (``prior``: see
    ``correspondences``): a homography from the pixels, undistorted by the lens ``nominal``
    has (if any: one view cannot tell the lens), to the belt (``intrinsics.fit_belt_plane``).
    The fit's calibration keeps that lens, and its similarity fields are the homography's
    nearest similarity."""
    px, mm, note = correspondences(image, target, pose, nominal, prior)
    plane = fit_belt_plane(px, mm, None, nominal.intrinsics, nominal.dist,
                           prior=nominal.homography)
    und = Calibration(plane.calibration).undistort(px)
    return CameraFit(plane.calibration, plane.rms_mm, plane.max_mm, plane.n_points,
                     _affine_rms(und, mm), plane.rms_mm, hint=note,
                     similarity_rms_mm=plane.similarity_rms_mm)


def camera_procedure(camera: Camera, wait: Waiter, target: Target, pose: TargetPose,
                     nominal: CameraCalibration, prior: bool = True) -> CameraFit:
    """The guided procedure: with the target lying at ``pose`` on the belt (belt stopped,
    backlight on), grab a frame and fit the calibration from its pixels."""
    frame: Frame = wait(camera.grab())
    return calibrate_camera_image(frame.image, target, pose, nominal, prior)
