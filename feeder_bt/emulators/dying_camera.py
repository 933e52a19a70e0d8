"""The camera's link dying the way cables die, at the frame source.

A GigE camera's link lives inside the vendor SDK (the GVCP control channel and its
heartbeat, the GVSP stream over UDP), so there is no TCP stream to put a
``linkproxy.LinkProxy`` on. ``DyingCameraSource`` stands in front of the emulated cell's
frame source (``PlantCameraSource`` or ``PylonPlantCamera``) instead and gives the driver
what a camera SDK hands it when its cable dies each of the proxy's ways, with the same
``cut(how)`` / ``restore()``:

``silence``
    a pulled cable: the trigger does not reach the camera, or its frame is lost on the
    wire; the grab never returns (the SDK's own wait aside). ``restore()`` plugs it back: a
    handle's next grab works, the grab that was waiting stays lost.
``half_open``
    as silence, and the camera dropped the host meanwhile (its heartbeat expired): every
    handle open at the cut stays dead after ``restore()``; only a handle opened afresh
    (``reopen()``) grabs again.
``refuse``
    the camera gone (powered off, unplugged: pylon's device removal): a grab fails at once,
    and so does opening it again, until ``restore()``.
``drip``
    a congested link: each frame arrives ``drip_s`` late (or at ``restore()``, when what
    was queued comes through).
``flood``
    noise on the line: the stream's payload overruns, and what the host assembles is not
    a frame of the camera's size (noise, larger than the image).
``garbage``
    a corrupting line: the frame's packets arrive damaged or not at all, and the SDK hands
    a failed grab result, not an image. Basler's pylon marks such a result
    ``GrabSucceeded() == false`` with ``GetErrorCode()`` / ``GetErrorDescription()``
    saying why (pylon C++ API, ``Pylon::CGrabResultData``; the C API's
    ``PylonGrabResult_t.ErrorCode``: "additional error code in case Status is
    gst_Failed"), as for a buffer grabbed incompletely: the driver raises an error, never
    hands the buffer on.

What each death is for the driver (``LatchedCamera``): a grab that hangs past its bound
or a frame of the wrong size is a lost link (``CommsLost``, the handle dropped and opened
afresh), as a silent or garbled line is on the other links; a removed camera and a
failed transfer are ``CommsLost`` from the source itself. None of it ever reaches the
recipe as an image of parts.
"""

from __future__ import annotations

import threading
import time
from typing import Any

import numpy as np

from feeder_bt.core.errors import CommsLost
from feeder_bt.hal.camera.sources import FrameSource

HOWS = ("silence", "half_open", "refuse", "drip", "flood", "garbage")
DRIP_S = 5.0          # a frame every several seconds: far past any grab's time-out
FLOOD_GROWTH = 2      # an overrun payload: this many times the frame's rows


class _Cable:
    """The link the handles of one camera share, and the camera behind it."""

    def __init__(self, source: FrameSource, seed: int, drip_s: float) -> None:
        self.source = source
        self.mode = "pass"
        self.drip_s = drip_s
        self.rng = np.random.default_rng(seed)
        self.changed = threading.Condition()
        self.handles: list[DyingCameraSource] = []
        self.closed = False

    def set(self, mode: str) -> None:
        with self.changed:
            self.mode = mode
            if mode == "half_open":
                for h in self.handles:
                    h.dead = True
            self.changed.notify_all()


class DyingCameraSource:
    """A ``FrameSource`` whose link dies on ``cut(how)``; ``reopen()`` opens another
    handle on the same camera through the same cable."""

    def __init__(self, source: FrameSource, seed: int = 0, drip_s: float = DRIP_S,
                 _cable: _Cable | None = None) -> None:
        self._cable = _cable if _cable is not None else _Cable(source, seed, drip_s)
        self.dead = False                 # half-open: this handle never delivers again
        self.closed = False
        self.grabs = 0
        with self._cable.changed:
            self._cable.handles.append(self)

    # ---------------------------------------------------------------- the cable
    def cut(self, how: str) -> None:
        """Start one death by its name (``HOWS``; ``half-open`` and ``silent`` too)."""
        how = how.replace("-", "_")
        how = "silence" if how == "silent" else how
        if how not in HOWS:
            raise ValueError(f"unknown link death {how!r}; one of: {', '.join(HOWS)}")
        self._cable.set(how)

    def restore(self) -> None:
        self._cable.set("pass")

    @property
    def mode(self) -> str:
        return self._cable.mode

    # ---------------------------------------------------------------- a frame source
    def capture(self) -> np.ndarray:
        cable = self._cable
        self.grabs += 1
        mode = cable.mode
        if self.closed:
            raise CommsLost("camera: this handle was closed (link lost)")
        if mode == "refuse":
            raise CommsLost("camera: the device was removed: powered off or unplugged "
                            "(link lost)")
        if self.dead or mode in ("silence", "half_open"):
            self._hang()
        image = cable.source.capture()        # triggered, exposed, on its way
        mode = cable.mode
        if self.dead or mode in ("silence", "half_open"):
            self._hang()                      # lost on the wire
        if mode == "drip":
            self._wait_drip()
        elif mode == "flood":
            h, w = image.shape[:2]
            return cable.rng.integers(0, 256, (h * FLOOD_GROWTH, w), dtype=np.uint8)
        elif mode == "garbage":
            raise CommsLost(f"camera: frame {self.grabs} lost: the grab result failed, the "
                            "buffer was incompletely grabbed (a corrupt transfer; link "
                            "lost)")
        return image

    def _hang(self) -> None:
        """A grab that never returns: until this handle is closed (then it fails)."""
        with self._cable.changed:
            while not (self.closed or self._cable.closed):
                self._cable.changed.wait()
        raise CommsLost("camera: the grab ended by closing the camera (link lost)")

    def _wait_drip(self) -> None:
        """The frame arrives ``drip_s`` late, or when the link is back."""
        cable = self._cable
        until = time.monotonic() + cable.drip_s
        with cable.changed:
            while cable.mode == "drip" and not (self.closed or cable.closed):
                left = until - time.monotonic()
                if left <= 0:
                    return
                cable.changed.wait(left)

    def reopen(self) -> DyingCameraSource:
        """Open the camera again through the same cable, this handle closed (what a driver
        does after a grab hung); refused while the camera is gone."""
        self._release()
        if self._cable.mode == "refuse":
            raise CommsLost("camera: not found: the device was removed (link lost)")
        return DyingCameraSource(self._cable.source, _cable=self._cable)

    def __getattr__(self, name: str) -> Any:
        """The camera's own extras (``prepare``, ``counts``) pass through the handle."""
        if name in ("prepare", "counts"):
            return getattr(self._cable.source, name)
        raise AttributeError(name)

    def _release(self) -> None:
        with self._cable.changed:
            self.closed = True
            if self in self._cable.handles:
                self._cable.handles.remove(self)
            self._cable.changed.notify_all()

    def close(self) -> None:
        """The cell is done with the camera: every handle ends and the camera closes."""
        self._release()
        with self._cable.changed:
            already, self._cable.closed = self._cable.closed, True
            self._cable.changed.notify_all()
        if not already:
            self._cable.source.close()
