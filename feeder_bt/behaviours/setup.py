"""Per-scenario set-up and clean-up (thesis 5.2.1: what a PSO's constructor and destructor
did): backlight, a cleared window for the golden image, encoder sync, robot to safety."""

from __future__ import annotations

from py_trees.common import Status

from ..jobs import Job
from .common import Ctx, JobLeaf, Leaf


class SetSignal(JobLeaf):
    def __init__(self, name: str, ctx: Ctx, signal: str, value: bool) -> None:
        super().__init__(name, ctx)
        self.signal, self.value = signal, value

    def start(self) -> Job:
        return self.ctx.hal.io.set(self.signal, self.value)


class ClearWindow(JobLeaf):
    """Run only the horizontal belt far enough to carry every part out of the camera's view."""

    def start(self) -> Job:
        cam = self.ctx.cell.camera
        window = cam.height_px * cam.calibration.mm_per_px
        largest = max(p.shape.diameter_mm or max(p.shape.size_mm) or 60.0
                      for p in self.ctx.scenario.parts.values())
        speed = self.ctx.cell.conveyors["horizontal"].max_mm_s
        return self.ctx.hal.conveyors["horizontal"].move(window + 2 * largest + 60.0, speed)


class SyncEncoders(Leaf):
    """With the belt at rest, tie the conveyor controller's count to the robot's (5.3.1)."""

    def update(self) -> Status:
        conv = self.ctx.hal.conveyors["horizontal"]
        self.ctx.encoder.reset(conv.position(), self.ctx.hal.robot_position.belt_encoder())
        return Status.SUCCESS
