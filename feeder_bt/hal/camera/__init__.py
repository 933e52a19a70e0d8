"""Cameras of a real (or emulated) cell: an image source plus the conveyor's encoder latch.
``open_source`` picks the source a cell description names; pylon is imported only for a
``pylon:`` camera (its SDK is optional)."""

from feeder_bt.core.model import CameraSpec
from feeder_bt.hal.camera.latched import LatchedCamera, LatchSource
from feeder_bt.hal.camera.sources import FrameSource, ReplaySource, VideoCaptureSource

__all__ = ["FrameSource", "LatchSource", "LatchedCamera", "ReplaySource",
           "VideoCaptureSource", "open_source"]


def open_source(spec: str, camera: CameraSpec | None = None) -> FrameSource:
    """The cell description's ``camera.source``: a device index, a URL, a folder or a file,
    or ``pylon:SERIAL`` (a GenICam camera set from ``camera.pylon``)."""
    if spec.startswith("pylon:"):
        from feeder_bt.hal.camera.pylon import PylonSource
        cam = camera if camera is not None else CameraSpec()
        return PylonSource(spec, cam.pylon, cam.exposure_ms, (cam.width_px, cam.height_px))
    if spec.isdigit() or "://" in spec:
        return VideoCaptureSource(spec)
    return ReplaySource(spec)
