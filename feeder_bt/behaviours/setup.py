"""Per-scenario set-up and clean-up (thesis 5.2.1: what a PSO's constructor and destructor
did): backlight, a cleared window for the golden image, encoder sync, robot to safety."""

from __future__ import annotations

from py_trees.common import Status

from feeder_bt.behaviours.base import Ctx, JobLeaf, Leaf
from feeder_bt.core.encoder import FreshAnchor
from feeder_bt.core.jobs import Job


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
    """With the belt at rest, tie the conveyor controller's count to the robot's (5.3.1),
    on a fresh, aged pair of reads (``encoder.FreshAnchor``, as commissioning does): the
    leaf looks at both caches each tick, never waiting on a link, and fails after
    ``timeout_s`` with the reason no pair came."""

    def __init__(self, name: str, ctx: Ctx, timeout_s: float = 5.0) -> None:
        super().__init__(name, ctx)
        self.timeout_s = timeout_s
        self.anchor: FreshAnchor | None = None
        self.started = 0.0

    def initialise(self) -> None:
        enc = self.ctx.cell.encoder
        self.anchor = FreshAnchor(enc.conveyor_bits, enc.robot_bits)
        self.started = self.ctx.now()

    def update(self) -> Status:
        assert self.anchor is not None
        conv = self.ctx.hal.conveyors["horizontal"]
        pos = self.ctx.hal.robot_position
        count = conv.position()                  # asks a real driver for a fresh TP read
        pair = self.anchor.offer(self.ctx.now(), count, conv.position_age(),
                                 pos.belt_encoder(), pos.age())
        if pair is not None:
            self.ctx.encoder.reset(*pair)
            return Status.SUCCESS
        if self.ctx.now() - self.started > self.timeout_s:
            self.feedback_message = f"no encoder sync in {self.timeout_s:g} s: {self.anchor.why}"
            return Status.FAILURE
        self.ctx.clock.wake_at(self.ctx.now() + 1e-3)    # look again next tick: no skipping
        return Status.RUNNING
