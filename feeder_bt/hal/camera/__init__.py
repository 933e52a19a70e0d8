"""Cameras of a real (or emulated) cell: an image source plus the conveyor's encoder latch."""

from feeder_bt.hal.camera.latched import LatchedCamera, LatchSource
from feeder_bt.hal.camera.sources import FrameSource, ReplaySource, VideoCaptureSource, open_source

__all__ = ["FrameSource", "LatchSource", "LatchedCamera", "ReplaySource",
           "VideoCaptureSource", "open_source"]
