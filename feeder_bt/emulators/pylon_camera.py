"""The emulated cell's camera through pylon's own camera emulator (``PYLON_CAMEMU=N``).

The plant renders the belt at the trigger pulse (which the Galil emulator's latch input
sees, as for ``PlantCameraSource``) into the image file the emulated camera serves, then
the camera is triggered and its frame comes back through pypylon — the whole locate path
runs through the vendor SDK.

What the emulator does (tried with pypylon 26.9, docs/real-cell.md): with ``ImageFileMode
On`` and ``ImageFilename`` a folder, it serves the folder's images in name order, reading
each file again when its turn comes; a folder of one file is read once and cached, so the
frame is written to both files of a ring of two. It has no electrical Line1: with
``TriggerSource Line1`` no frame comes until ``TriggerSoftware`` is executed, so for a
line-triggered cell this bridge issues that software trigger at the Galil pulse, standing
in for the wire.
"""

from __future__ import annotations

import os
import shutil
import tempfile
from pathlib import Path

import cv2
import numpy as np

from feeder_bt.core.model import CameraSpec
from feeder_bt.hal.camera.pylon import PylonSource
from feeder_bt.sim.realtime import Plant

RING = ("frame0.bmp", "frame1.bmp")      # BMP: the cheapest format to write and read


class ImageFiles:
    """The folder an emulated pylon camera serves its frames from."""

    def __init__(self, size: tuple[int, int]) -> None:
        self.dir = Path(tempfile.mkdtemp(prefix="feeder-camemu-"))
        self.size = size
        self.write(np.zeros((size[1], size[0]), np.uint8))

    def configure(self, cam) -> None:
        """Camera features the emulator has and a real camera does not (CamEmu only)."""
        cam.TestImageSelector.Value = "Off"
        cam.ImageFilename.Value = str(self.dir)
        cam.ImageFileMode.Value = "On"

    def write(self, img: np.ndarray) -> None:
        """The next frame, replaced atomically (the emulator never reads half a file)."""
        for name in RING:
            tmp = self.dir.parent / f".{self.dir.name}-{name}"
            cv2.imwrite(str(tmp), img)
            os.replace(tmp, self.dir / name)

    def remove(self) -> None:
        shutil.rmtree(self.dir, ignore_errors=True)


class PylonPlantCamera:
    """A ``FrameSource`` for ``--hal emulated`` when ``camera.source`` is ``pylon:...``."""

    def __init__(self, plant: Plant, camera: CameraSpec, faults=None) -> None:
        self.plant = plant
        self.faults = faults              # emulators.faults.FaultPlan, rules for "camera"
        self.index = 0
        self._skip_pulse = False
        self.files = ImageFiles((camera.width_px, camera.height_px))
        try:
            self.source = PylonSource(camera.source, camera.pylon, camera.exposure_ms,
                                      (camera.width_px, camera.height_px),
                                      before_trigger=self._render, line_pulse=self._pulse,
                                      configure=self.files.configure)
        except BaseException:
            self.files.remove()
            raise

    def _render(self) -> None:
        """The trigger pulse: the Galil latches it; the belt is drawn as it is now."""
        rule = self.faults.check("camera", "TRIGGER") if self.faults is not None else None
        if rule is not None:
            self._inject(rule.kind)
        self._pulse_plant()

    def _inject(self, kind: str) -> None:
        """A camera fault at this trigger (docs/real-cell.md, "An industrial camera")."""
        cam = self.source.cam
        if kind == "drop":                 # the camera disappears (closed, unplugged)
            cam.Close()
        elif kind == "no_frame":           # the trigger brings nothing: the buffer fails
            cam.ForceFailedBufferCount.Value = 1
            cam.ForceFailedBuffer.Execute()
        elif kind == "extra_trigger":      # a second pulse on the wire: latched and exposed
            self._pulse_plant()
            ready = self.source.pylon.TimeoutHandling_Return
            cam.WaitForFrameTriggerReady(5000, ready)
            cam.ExecuteSoftwareTrigger()
            cam.WaitForFrameTriggerReady(5000, ready)    # exposed: the next pulse is seen
        elif kind == "wrong_format":       # someone set the camera otherwise
            cam.StopGrabbing()
            cam.ImageFileMode.Value = "Off"
            cam.TestImageSelector.Value = "Testimage1"
            cam.PixelFormat.Value = "Mono16"
            cam.StartGrabbing(self.source.pylon.GrabStrategy_OneByOne)

    def _pulse_plant(self) -> None:
        cam = self.plant.hal.camera
        with self.plant.lock:
            self.index += 1
            t = self.plant.trigger()
            render = cam.snapshot(t, self.index)
        self.files.write(render())          # outside the lock: the plant keeps running

    def _pulse(self) -> None:
        """The Line1 wire, bridged: the emulator takes no electrical line input."""
        self.source.cam.ExecuteSoftwareTrigger()

    def capture(self) -> np.ndarray:
        return self.source.capture()

    def counts(self) -> dict[str, int]:
        return self.source.counts()

    def close(self) -> None:
        self.source.close()
        self.files.remove()
