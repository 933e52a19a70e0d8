"""Guided calibration (thesis 8.2.1.7): camera <-> belt, belt <-> robot, tool offsets.

The camera: ``calibrate_camera_views`` (named images: the lens from several views, the
belt plane from the first; ``camera_model``), or ``calibrate_camera_image`` for one view.

Pure fitting functions (``fit_camera``, ``fit_belt``, ``fit_tool``) and small procedures
that drive a cell through the HAL interfaces only, so they run on the simulated cell now
and on a real cell once its drivers exist. ``files`` reads and writes calibration files.
"""

from feeder_bt.calibration.belt import BeltFit, BeltTouch, belt_procedure, fit_belt
from feeder_bt.calibration.camera import (
    DEFAULT_TARGETS,
    CameraFit,
    Target,
    TargetPose,
    fit_camera,
    window_error_mm,
)
from feeder_bt.calibration.camera_model import (
    CameraResult,
    calibrate_camera_image,
    calibrate_camera_views,
    camera_procedure,
)
from feeder_bt.calibration.files import (
    apply_calibration_file,
    read_camera_calibration,
    write_calibration_file,
)
from feeder_bt.calibration.procedure import CalibrationError, sim_waiter
from feeder_bt.calibration.tool import ToolFit, ToolTouch, fit_tool, tool_procedure

__all__ = [
    "DEFAULT_TARGETS", "BeltFit", "BeltTouch", "CalibrationError", "CameraFit", "CameraResult",
    "Target", "calibrate_camera_views",
    "TargetPose", "ToolFit", "ToolTouch", "apply_calibration_file", "belt_procedure",
    "calibrate_camera_image", "camera_procedure", "fit_belt", "fit_camera", "fit_tool",
    "read_camera_calibration", "sim_waiter", "tool_procedure", "window_error_mm",
    "write_calibration_file",
]
