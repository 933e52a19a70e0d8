"""Part presentation: run the conveyors (continuous) or advance on request (incremental)."""

from __future__ import annotations

from py_trees.common import Status

from feeder_bt.behaviours.base import Ctx, JobLeaf, Leaf
from feeder_bt.behaviours.keys import PRESENT, SPEEDS
from feeder_bt.core.jobs import Job, JobState


class RunConveyors(Leaf):
    """Keep both conveyors at the blackboard speeds; RUNNING for as long as it is ticked.

    The incline runs at ``incline_pct`` % of the horizontal speed (thesis 8.1.3)."""

    READS = (SPEEDS.HORIZONTAL, SPEEDS.INCLINE, PRESENT.HOLD)
    WRITES = (PRESENT.ERROR,)

    def __init__(self, name: str, ctx: Ctx) -> None:
        super().__init__(name, ctx)
        self.jobs: list[Job] = []
        self.commanded: tuple[float, float] | None = None
        self._message_of: tuple[float, float] | None = None
        self._message = ""

    def initialise(self) -> None:
        self.commanded = None
        self.jobs = []

    def update(self) -> Status:
        h = float(self.bb.get(SPEEDS.HORIZONTAL))
        i = h * float(self.bb.get(SPEEDS.INCLINE)) / 100.0
        if self.bb.get(PRESENT.HOLD):
            i = 0.0
        if self.commanded != (h, i):
            conv = self.ctx.hal.conveyors
            self.jobs = [conv["horizontal"].set_speed(h), conv["incline"].set_speed(i)]
            self.commanded = (h, i)
            self.ctx.stats.emit(self.ctx.now(), "speeds", horizontal_mm_s=h, incline_mm_s=i)
        for job in self.jobs:
            if job.done and not job.ok:
                return self._failed(job.error)
        for conv in self.ctx.hal.conveyors.values():
            jam = conv.fault()
            if jam is not None:
                return self._failed(jam)
        if self._message_of != (h, i) or self.feedback_message is not self._message:
            # formatted when the speeds change, not every tick: the same text
            self._message_of = (h, i)
            self._message = f"horizontal {h:.0f} mm/s, incline {i:.0f} mm/s"
            self.feedback_message = self._message
        return Status.RUNNING

    def _failed(self, error) -> Status:
        self.bb.set(PRESENT.ERROR, error)
        self.feedback_message = str(error)
        self.commanded = None               # after the recovery, command the speeds afresh
        return Status.FAILURE

    def terminate(self, new_status: Status) -> None:
        # pre-empted while running: stop. After a FAILURE the recovery branch stops them.
        if (new_status is Status.INVALID and self.status is Status.RUNNING
                and self.commanded is not None):
            for job in self.jobs:
                job.cancel()                # no-op for jobs already done
            for conv in self.ctx.hal.conveyors.values():
                conv.stop()
            self.commanded = None


class ServeAdvance(JobLeaf):
    """Incremental mode: wait for a request from the locator, then advance the belts."""

    fault_key = PRESENT.ERROR
    READS = (PRESENT.REQUEST, PRESENT.COMPLETED)
    WRITES = (PRESENT.REQUEST, PRESENT.COMPLETED, PRESENT.ERROR)

    def __init__(self, name: str, ctx: Ctx) -> None:
        super().__init__(name, ctx)
        self.kind: str | None = None

    def initialise(self) -> None:
        self.kind = None
        self.job = None

    def update(self) -> Status:
        if self.job is None:
            self.kind = self.bb.get(PRESENT.REQUEST)
            if self.kind is None:
                return Status.RUNNING
            self.job = self.start()
        return super().update()

    def start(self) -> Job:
        p = self.ctx.scenario.present
        conv = self.ctx.hal.conveyors
        h_speed = self.ctx.cell.conveyors["horizontal"].max_mm_s
        if self.kind == "big":
            # one job for both belts: done when both are, failed or cancelled together
            return _all([conv["incline"].move(p.big_advance_incline_mm, h_speed),
                         conv["horizontal"].move(p.big_advance_mm, h_speed)])
        return conv["horizontal"].move(p.small_advance_mm, h_speed)

    def on_success(self, result: object) -> Status:
        self.bb.set(PRESENT.REQUEST, None)
        self.bb.set(PRESENT.COMPLETED, self.bb.get(PRESENT.COMPLETED) + 1)
        return Status.SUCCESS


class Shake(JobLeaf):
    """Jam recovery: jog the horizontal belt back and forth to free the parts."""

    fault_key = PRESENT.ERROR
    WRITES = (PRESENT.ERROR,)
    AMPLITUDE_MM, CYCLES = 20.0, 3

    def start(self) -> Job:
        return self.ctx.hal.conveyors["horizontal"].shake(self.AMPLITUDE_MM, self.CYCLES)

    def on_success(self, result: object) -> Status:
        self.ctx.stats.recovered(self.ctx.now(), "conveyor")
        return Status.SUCCESS


class FirstJamIn(Leaf):
    """Condition: no other jam in the last ``window_s`` — a second one soon after a shake
    means shaking does not help, and the operator must look."""

    def __init__(self, name: str, ctx: Ctx, window_s: float = 60.0) -> None:
        super().__init__(name, ctx)
        self.window_s = window_s
        self.last: float | None = None

    def update(self) -> Status:
        now = self.ctx.now()
        first = self.last is None or now - self.last > self.window_s
        self.last = now
        return Status.SUCCESS if first else Status.FAILURE


class StopConveyors(JobLeaf):
    def start(self) -> Job:
        jobs = [c.stop() for c in self.ctx.hal.conveyors.values()]
        return jobs[0] if len(jobs) == 1 else _all(jobs)


class _AllJob(Job):
    """Polling it polls its parts: a worker's job (``FutureJob``) ends only when polled."""

    def __init__(self, name: str, parts: list[Job]) -> None:
        super().__init__(name)
        self.parts = parts

    def poll(self):
        if self.state is JobState.RUNNING:
            for j in self.parts:
                j.poll()
        return self.state


def _all(jobs: list[Job]) -> Job:
    """One job that ends when every job has ended (first failure wins)."""
    combined = _AllJob("+".join(j.name for j in jobs), jobs)
    remaining = set(range(len(jobs)))
    cancelling: list[bool] = []

    def cancel_parts() -> None:     # cancelling the whole cancels every part
        cancelling.append(True)
        for j in jobs:
            j.cancel()

    combined._on_cancel = cancel_parts

    def done(i: int, j: Job) -> None:
        if cancelling:
            return
        remaining.discard(i)
        if not j.ok and j.error is not None:
            combined.fail(j.error)
        elif not remaining:
            combined.succeed(None)

    for i, j in enumerate(jobs):
        j.add_done_callback(lambda jj, i=i: done(i, jj))
    return combined
