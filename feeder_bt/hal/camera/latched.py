"""A camera whose trigger also latches the conveyor encoder (thesis section 2.3).

The trigger line is wired both to the camera and to the conveyor controller's latch
input, so the image and the belt position are taken at the same instant. A grab arms the
latch, triggers the source, then reads the latched count — all on the camera's own
worker, so the tick never waits.
"""

from __future__ import annotations

import time
from concurrent.futures import ThreadPoolExecutor
from typing import Protocol

from feeder_bt.core.clock import Clock
from feeder_bt.core.errors import GrabFailed, HalError
from feeder_bt.core.jobs import DoneJob, FutureJob, Job
from feeder_bt.hal.camera.sources import FrameSource
from feeder_bt.hal.interfaces import Frame


class LatchSource(Protocol):
    """The conveyor controller's position latch (a Galil axis: ``AL`` / ``RL``)."""

    def arm_latch(self) -> Job: ...

    def read_latch(self) -> Job: ...


def wait_job(job: Job, timeout_s: float, what: str) -> object:
    """Wait for a job from a worker thread (never from the tick); its result or its error."""
    deadline = time.monotonic() + timeout_s
    while not job.done:
        if time.monotonic() > deadline:
            job.cancel()
            raise GrabFailed(f"{what}: no answer in {timeout_s:g} s")
        time.sleep(0.001)
    if not job.ok:
        raise job.error or HalError(f"{what} failed")
    return job.result


class LatchedCamera:
    def __init__(self, source: FrameSource, clock: Clock, latch: LatchSource | None = None,
                 timeout_s: float = 2.0) -> None:
        self.source, self.clock, self.latch = source, clock, latch
        self.timeout_s = timeout_s
        self.worker = ThreadPoolExecutor(max_workers=1, thread_name_prefix="camera")
        self.frames = 0
        self.exposure_ms: float | None = None

    def _grab(self, index: int) -> Frame:
        prepare = getattr(self.source, "prepare", None)
        if prepare is not None:       # a camera counting its frames drops strays before AL
            prepare()
        if self.latch is not None:
            wait_job(self.latch.arm_latch(), self.timeout_s, "arming the encoder latch")
        t = self.clock.now()
        image = self.source.capture()
        latch = 0
        if self.latch is not None:
            latch = int(wait_job(self.latch.read_latch(), self.timeout_s,   # type: ignore[arg-type]
                                 "reading the encoder latch"))
        return Frame(image=image, latch=latch, t=t, index=index)

    def grab(self) -> Job:
        self.frames += 1
        return FutureJob("camera.grab", self.worker.submit(self._grab, self.frames), self.clock)

    def set_exposure(self, ms: float) -> Job:
        self.exposure_ms = ms       # sources without an exposure control ignore it
        return DoneJob("camera.set_exposure")

    def close(self) -> None:
        self.worker.shutdown(wait=True, cancel_futures=True)
        self.source.close()
