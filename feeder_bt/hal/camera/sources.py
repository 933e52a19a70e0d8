"""Where images come from: a camera or stream through OpenCV, or recorded images.

A source only captures; pairing the image with the belt's position is the job of
``LatchedCamera`` (the trigger is mirrored to the conveyor controller's latch input).
"""

from __future__ import annotations

from pathlib import Path
from typing import Protocol

import cv2
import numpy as np

from feeder_bt.core.errors import ConfigError, GrabFailed

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".pgm")


class FrameSource(Protocol):
    """A camera's frames. A source may also offer ``reopen()``: a fresh handle on the same
    camera, the old one closed, which ``LatchedCamera`` takes after a grab that hung."""

    def capture(self) -> np.ndarray:
        """Trigger and return one grey uint8 image; raise ``GrabFailed`` when none comes,
        ``CommsLost`` when the camera's link is gone (removed, a corrupt transfer)."""

    def close(self) -> None: ...


def as_frame(img: np.ndarray) -> np.ndarray:
    """What a camera delivers (colour, 16-bit) made the uint8 grey frame the cell passes
    on. The locator's ``to_grey`` refuses non-uint8 instead: past this point a frame of
    another depth is a bug, not a camera's choice."""
    if img.ndim == 3:
        img = cv2.cvtColor(img, cv2.COLOR_BGR2GRAY)
    if img.dtype != np.uint8:
        img = cv2.normalize(img, None, 0, 255, cv2.NORM_MINMAX).astype(np.uint8)
    return img


STREAM_TIMEOUT_S = 5.0


class VideoCaptureSource:
    """A device index ("0") or a stream URL, read through ``cv2.VideoCapture``."""

    def __init__(self, spec: str | int, timeout_s: float = STREAM_TIMEOUT_S) -> None:
        self.spec = spec
        target = int(spec) if isinstance(spec, str) and spec.isdigit() else spec
        # a silent stream server would hold the open (and each read) for OpenCV's own
        # 30 s: both are bounded (the FFmpeg and GStreamer back-ends honour these)
        ms = int(timeout_s * 1000)
        self.cap = cv2.VideoCapture(target, cv2.CAP_ANY,
                                    [cv2.CAP_PROP_OPEN_TIMEOUT_MSEC, ms,
                                     cv2.CAP_PROP_READ_TIMEOUT_MSEC, ms])
        if not self.cap.isOpened():
            raise ConfigError(f"cannot open camera {spec!r} (no such device or stream)",
                              key="camera.source")

    def capture(self) -> np.ndarray:
        ok, img = self.cap.read()
        if not ok or img is None:
            raise GrabFailed(f"camera {self.spec!r} returned no image")
        return as_frame(img)

    def close(self) -> None:
        self.cap.release()


class ReplaySource:
    """Recorded images, in name order, or the frames of a video file; loops at the end.

    For tuning a recipe on a real cell's images without the cell."""

    def __init__(self, path: str | Path, loop: bool = True) -> None:
        self.path = Path(path)
        self.loop = loop
        self.index = 0
        self.files: list[Path] = []
        self.cap: cv2.VideoCapture | None = None
        if self.path.is_dir():
            self.files = sorted(p for p in self.path.iterdir()
                                if p.suffix.lower() in IMAGE_SUFFIXES)
            if not self.files:
                raise ConfigError(f"{self.path}: no images ({', '.join(IMAGE_SUFFIXES)})",
                                  key="camera.source")
        elif self.path.is_file():
            self.cap = cv2.VideoCapture(str(self.path))
            if not self.cap.isOpened():
                raise ConfigError(f"{self.path}: not a video file OpenCV can read",
                                  key="camera.source")
        else:
            raise ConfigError(f"{self.path}: no such folder or video file", key="camera.source")

    def capture(self) -> np.ndarray:
        if self.cap is not None:
            ok, img = self.cap.read()
            if not ok and self.loop:
                self.cap.set(cv2.CAP_PROP_POS_FRAMES, 0)
                ok, img = self.cap.read()
            if not ok or img is None:
                raise GrabFailed(f"{self.path}: no more frames")
            return as_frame(img)
        if self.index >= len(self.files):
            if not self.loop:
                raise GrabFailed(f"{self.path}: no more images")
            self.index = 0
        f = self.files[self.index]
        self.index += 1
        img = cv2.imread(str(f), cv2.IMREAD_GRAYSCALE)
        if img is None:
            raise GrabFailed(f"{f}: not an image OpenCV can read")
        return img

    def close(self) -> None:
        if self.cap is not None:
            self.cap.release()
