"""The emulated camera: renders the plant's belt at the trigger, which the plant also
passes to the Galil emulator's latch input (the wiring of thesis section 2.3)."""

from __future__ import annotations

import numpy as np

from feeder_bt.sim.realtime import Plant


class PlantCameraSource:
    def __init__(self, plant: Plant) -> None:
        self.plant = plant
        self.index = 0

    def capture(self) -> np.ndarray:
        cam = self.plant.hal.camera
        with self.plant.lock:
            self.index += 1
            t = self.plant.trigger()
            render = cam.snapshot(t, self.index)
        return render()        # outside the lock: the plant keeps running meanwhile

    def close(self) -> None:
        pass
