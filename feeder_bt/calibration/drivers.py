"""The calibration procedures on a cell behind the drivers: a real cell or the emulators.

The procedures (``belt_procedure``, ``tool_procedure``, ``camera_procedure``) use the HAL
interfaces only; what differs from the simulated cell is how they wait (``real_waiter``:
on the real clock), who puts the tool on the marker and how fresh the robot's reported
pose is:

* a real cell: the operator jogs the robot with the teach pendant and presses Enter
  (``OperatorTouch``); the robot's pose and belt count are then read afresh from the
  controller (``refresh``);
* the emulators (``--hal emulated``): a scripted operator (``PlantToucher``) commands the
  robot through the V+ driver onto a marker on the emulated plant's belt, with a little
  noise — so the whole chain (Galil driver moving the belt, V+ driver moving the robot and
  reporting pose and encoder) is exercised as on the real cell.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from typing import Any

import numpy as np

from feeder_bt.calibration.procedure import CalibrationError, Waiter
from feeder_bt.core.jobs import Job
from feeder_bt.hal.interfaces import Hal, Pose

POLL_S = 0.005


def real_waiter(timeout_s: float = 120.0) -> Waiter:
    """A ``Waiter`` on the real clock: poll the job until it ends (its driver's worker
    finishes it); its result, or its typed error."""
    def wait(job: Job) -> Any:
        deadline = time.monotonic() + timeout_s
        while not job.done:
            if time.monotonic() > deadline:
                job.cancel()
                raise CalibrationError(f"{job.name} did not finish within {timeout_s:g} s")
            time.sleep(POLL_S)
        if job.error is not None:
            raise job.error
        return job.result
    return wait


def refresh(hal: Hal) -> Callable[[], None]:
    """After a touch: read the robot's pose and belt count from the controller now, not
    from the position poller's cache (which may predate the last move)."""
    read = getattr(hal.robot_position, "read_once", None)
    return read if read is not None else (lambda: None)


class OperatorTouch(Job):
    """Ends when the operator, having jogged the tool onto the point, presses Enter."""

    def __init__(self, prompt: str, ask: Callable[[str], str] = input) -> None:
        super().__init__("operator.touch")

        def run() -> None:
            try:
                ask(prompt)
            except EOFError:
                self.fail(CalibrationError("no operator at the terminal (end of input)"))
                return
            self.succeed(None)

        threading.Thread(target=run, name="operator-touch", daemon=True).start()


class PlantToucher:
    """The scripted operator of the emulated cell: a marker stuck on the emulated plant's
    belt, the robot commanded through its driver onto it (or onto a fixed point) with the
    tool turned as asked. The robot frame is the belt frame on the emulated cell."""

    def __init__(self, plant, robot, tool_offset_mm: tuple[float, float] = (0.0, 0.0),
                 noise_mm: float = 0.05, seed: int = 1) -> None:
        self.plant, self.robot = plant, robot
        self.tool = np.asarray(tool_offset_mm, dtype=float)
        self.noise_mm = noise_mm
        self.rng = np.random.default_rng([seed, 11])
        self.marker: tuple[float, float, float] | None = None

    def put_marker(self, x_mm: float, y_mm: float) -> None:
        with self.plant.lock:
            world = self.plant.world
            self.marker = (x_mm, y_mm, world.horizontal.pos(world.now()))

    def marker_xy(self) -> np.ndarray:
        if self.marker is None:
            raise CalibrationError("put_marker first")
        x, y, p0 = self.marker
        with self.plant.lock:
            world = self.plant.world
            return np.array([x + world.horizontal.pos(world.now()) - p0, y])

    def touch(self, point_xy: np.ndarray, rz_deg: float = 0.0) -> Job:
        r = np.radians(rz_deg)
        rot = np.array([[np.cos(r), -np.sin(r)], [np.sin(r), np.cos(r)]])
        flange = np.asarray(point_xy, dtype=float) - rot @ self.tool
        flange = flange + self.rng.normal(0.0, self.noise_mm, size=2)
        return self.robot.move_to(Pose(float(flange[0]), float(flange[1]), 0.0, rz_deg))

    def touch_marker(self) -> Job:
        return self.touch(self.marker_xy())
