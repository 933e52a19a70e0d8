"""Cameras of a real (or emulated) cell: an image source plus the conveyor's encoder latch."""

from .latched import LatchedCamera, LatchSource
from .sources import FrameSource, ReplaySource, VideoCaptureSource, open_source

__all__ = ["FrameSource", "LatchSource", "LatchedCamera", "ReplaySource",
           "VideoCaptureSource", "open_source"]
