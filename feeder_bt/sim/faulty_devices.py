"""The simulated cell's devices as a fault plan makes them fail (``faults.py``).

Each wraps one device of a ``SimHal`` and keeps its interface: calls on a link that is down
fail at once, reads return what the controller last sent, and jobs in flight end with the
fault. The robot's replies come through ``ReplyJob``: a dropped link loses the *reply*, not
the motion, which goes on in the world to its end. Anything a wrapper does not override
goes to the wrapped device. The ``FaultInjector`` decides when; these say how each device
shows it.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING, Any

from feeder_bt.core.errors import GrabFailed, HalError, ServoTimeout
from feeder_bt.core.jobs import DoneJob, Job, JobState
from feeder_bt.hal.interfaces import IoChange, PickTarget, Pose
from feeder_bt.sim.devices import TimedJob
from feeder_bt.sim.world import World

if TYPE_CHECKING:
    from feeder_bt.sim.faults import FaultInjector

POWER_OFF = "robot power is off: run the recovery program"


def _event_time(world: World, seq: int | None) -> float | None:
    """When the world's scheduled event ``seq`` is due (None if it is not scheduled)."""
    return next((t for t, s, _ in world._timed if s == seq), None)


def _fail_timed(world: World, job: Job, error: HalError) -> None:
    """End a running job with ``error`` now: its completion is unscheduled (so a pick's
    grip or a place's release never happens) and the robot is no longer busy with it."""
    if job.done:
        return
    if isinstance(job, TimedJob) and job.seq is not None:
        world.unschedule(job.seq)
        job.seq = None
    if world.robot_busy is job:
        world.robot_busy = None
    job.fail(error)


class _Wrapper:
    """Anything a wrapper does not override goes to the wrapped device."""

    def __init__(self, inner: Any, inj: FaultInjector) -> None:
        self._inner = inner
        self._inj = inj

    def __getattr__(self, name: str) -> Any:
        if name in ("_inner", "_inj"):         # not set yet (a copy being made)
            raise AttributeError(name)
        return getattr(self._inner, name)


class _Tracking(_Wrapper):
    """A wrapper that remembers its jobs in flight, so a fault can end them."""

    def __init__(self, inner: Any, inj: FaultInjector) -> None:
        super().__init__(inner, inj)
        self._jobs: list[Job] = []

    def _track(self, job: Job) -> Job:
        if not job.done:
            self._jobs.append(job)
            job.add_done_callback(self._untrack)
        return job

    def _untrack(self, job: Job) -> None:
        if job in self._jobs:
            self._jobs.remove(job)

    def _fail_jobs(self, err: HalError, which: Callable[[Job], bool] = lambda job: True
                   ) -> bool:
        jobs = [j for j in self._jobs if which(j) and not j.done]
        for job in jobs:
            _fail_timed(self._inj.world, job, err)
        return bool(jobs)


class ReplyJob(Job):
    """The cell's side of a robot command: it ends when the controller's reply arrives.
    When the link drops the reply is lost (``lose``) while the motion (``inner``) goes
    on in the world; ``before_reply`` may cut the link just as the reply would leave."""

    def __init__(self, inner: Job, before_reply: Callable[[Job], None] | None = None) -> None:
        super().__init__(inner.name)
        self.inner = inner
        self.before_reply = before_reply
        inner.add_done_callback(self._reply)

    def _reply(self, inner: Job) -> None:
        if self.before_reply is not None and not self.done:
            self.before_reply(inner)            # may lose this reply
        if inner.state is JobState.SUCCEEDED:
            self.succeed(inner.result)
        elif inner.state is JobState.FAILED:
            self.fail(inner.error)             # type: ignore[arg-type]
        else:
            self._finish(inner.state, error=inner.error)

    def _on_cancel(self) -> None:
        self.inner.cancel()


class FaultyRobot(_Tracking):
    """The robot with arm power and the Adept link: motions fail at once while either is
    off; ``recover()`` turns the power back on. Every command's reply comes through a
    ``ReplyJob``, which a dropped link fails while the motion goes on."""

    def _refuse(self, name: str, motion: bool = True) -> Job | None:
        refused = self._inj.refused("adept", name)
        if refused is None and motion and not self._inj.power_on:
            refused = DoneJob(name, error=ServoTimeout(POWER_OFF))
        return refused

    def _reply(self, inner: Job, phase: str | None = None) -> Job:
        if inner.done:
            return inner
        cut = None
        if phase is not None:
            def cut(job: Job) -> None:
                if job.ok:
                    self._inj.cut(phase, self._inj.world.t)
        return self._track(ReplyJob(inner, cut))

    def lose_replies(self, err: HalError) -> bool:
        """The link dropped: every reply in flight is lost (the motions go on)."""
        return self._fail_jobs(err)

    def pick(self, target: PickTarget) -> Job:
        self._inj.cut("before_pick", self._inj.world.now())
        refused = self._refuse("robot.pick")
        if refused is not None:
            return refused
        job = self._inner.pick(target)
        if isinstance(job, TimedJob) and not job.done:
            self._inj.on_pick(job, target)
        return self._reply(job, "after_grip")

    def place(self, pose: Pose) -> Job:
        refused = self._refuse("robot.place")
        if refused is not None:
            return refused
        job = self._inner.place(pose)
        w = self._inj.world
        t_end = _event_time(w, job.seq) if isinstance(job, TimedJob) else None
        if t_end is not None and any(c.phase == "during_place" for c in self._inj._cuts):
            t_mid = w.t + 0.5 * (t_end - w.t)
            w.schedule(t_mid, lambda t: self._inj.cut("during_place", t))
        return self._reply(job, "after_release")

    def move_to(self, pose: Pose) -> Job:
        return self._refuse("robot.move") or self._reply(self._inner.move_to(pose))

    def move_safe(self) -> Job:
        return self._refuse("robot.move") or self._reply(self._inner.move_safe())

    def set_speed(self, pct: float) -> Job:
        return self._refuse("robot.set_speed", motion=False) or self._inner.set_speed(pct)

    def recover(self) -> Job:
        refused = self._refuse("robot.recover", motion=False)
        if refused is not None:
            return refused
        job = self._inner.recover()
        job.add_done_callback(self._inj.on_recovered)
        return self._reply(job)

    def holding(self) -> bool:
        return self._inner.holding()

    def held(self) -> Job:
        return self._refuse("robot.held", motion=False) or self._reply(self._inner.held())


class FaultyRobotPosition(_Wrapper):
    """While the Adept link is down, reads return what the controller last sent."""

    _frozen: tuple[int, Pose] | None = None

    def freeze(self, t: float) -> None:
        self._frozen = (self._inj.world.robot_count(t), self._inj.world.robot_pose)

    def _live(self) -> bool:
        return not self._inj.is_down("adept")

    def belt_encoder(self) -> int:
        if self._live() or self._frozen is None:
            return self._inner.belt_encoder()
        return self._frozen[0]

    def age(self) -> float | None:
        return self._inner.age() if self._live() else None

    def pose(self) -> Pose:
        if self._live() or self._frozen is None:
            return self._inner.pose()
        return self._frozen[1]


class FaultyConveyor(_Tracking):
    """A conveyor on the Galil link, which may stall (``fault()``) until the next motion
    command. While the link is down, commands fail at once and reads return the last
    values; the belt goes on as it was commanded until the card's host watchdog stops it
    (``FaultInjector._watchdog``), which ``fault()`` reports once the link is back."""

    def __init__(self, inner: Any, inj: FaultInjector) -> None:
        super().__init__(inner, inj)
        self.name: str = inner.name
        self.jam: HalError | None = None
        self.watchdog: HalError | None = None   # the card's watchdog stopped this belt
        self._frozen: tuple[float, int] | None = None

    def _motion(self, method: str, *args: Any) -> Job:
        refused = self._inj.refused("galil", f"{self.name}.{method}")
        if refused is not None:
            return refused
        if self.jam is not None:
            self.jam = None
            self._inj.jam_cleared()
        self.watchdog = None
        return self._track(getattr(self._inner, method)(*args))

    def set_speed(self, mm_s: float) -> Job:
        return self._motion("set_speed", mm_s)

    def move(self, distance_mm: float, mm_s: float) -> Job:
        return self._motion("move", distance_mm, mm_s)

    def stop(self) -> Job:
        return self._motion("stop")

    def shake(self, amplitude_mm: float, cycles: int) -> Job:
        return self._motion("shake", amplitude_mm, cycles)

    def travelled(self, distance_mm: float) -> Job:
        refused = self._inj.refused("galil", f"{self.name}.travelled")
        if refused is not None:
            return refused
        return self._track(self._inner.travelled(distance_mm))

    def speed(self) -> float:
        if not self._inj.is_down("galil") or self._frozen is None:
            return self._inner.speed()
        return self._frozen[0]

    def position(self) -> int:
        if not self._inj.is_down("galil") or self._frozen is None:
            return self._inner.position()
        return self._frozen[1]

    def position_age(self) -> float | None:
        return None if self._inj.is_down("galil") else self._inner.position_age()

    def fault(self) -> HalError | None:
        self._inj.world.now()
        if self.jam is not None:
            self._inj.jam_read()
            return self.jam
        if self.watchdog is not None and not self._inj.is_down("galil"):
            return self.watchdog                # the card's W, heard once the link is back
        return None

    # -- for the injector --------------------------------------------------------------
    def freeze(self, t: float, err: HalError) -> bool:
        """The link dropped at ``t``: remember the reads, fail the jobs in flight (the
        belt's motion itself is not touched). True if any job failed."""
        self._frozen = (self._inner.speed(), self._inj.world.galil_count(t))
        return self._fail_jobs(err)

    def jammed(self, err: HalError) -> bool:
        """The belt stalled: ``fault()`` reports it, motions in flight end with it (their
        planned profile is gone); distance notifications wait for the belt to move."""
        self.jam = err
        return self._fail_jobs(err, lambda job: isinstance(job, TimedJob))


class FaultyCamera(_Tracking):
    """The camera on its own link; a grab may come back with no image (``GrabFailed``)."""

    def grab(self) -> Job:
        inj = self._inj
        refused = inj.refused("camera", "camera.grab")
        if refused is not None:
            return refused
        if inj._draw("grab_failed"):
            if hasattr(self._inner, "frames"):
                self._inner.frames += 1       # the frame index is used: later noise unchanged
            w = inj.world
            job = TimedJob("camera.grab", w)

            def fail(t: float) -> None:
                job.seq = None
                inj._record(t, "grab_failed", "camera", "grab returned no image")
                job.fail(GrabFailed("camera: no image (grab failed)"))

            return job.at(w.now() + w.cell.camera.grab_s, fail)
        return self._track(self._inner.grab())

    def set_exposure(self, ms: float) -> Job:
        return self._inj.refused("camera", "camera.set_exposure") or self._inner.set_exposure(ms)

    def fail_in_flight(self, err: HalError) -> bool:
        return self._fail_jobs(err)


class FaultyIO(_Wrapper):
    """Digital I/O that also reports the input changes the injector makes (the e-stop)."""

    def __init__(self, inner: Any, inj: FaultInjector) -> None:
        super().__init__(inner, inj)
        self._changes: list[IoChange] = []

    def get(self, signal: str) -> bool:
        self._inj.world.now()
        return self._inner.get(signal)

    def set(self, signal: str, value: bool) -> Job:
        return self._inner.set(signal, value)

    def changes(self) -> list[IoChange]:
        self._inj.world.now()
        out, self._changes = self._inner.changes() + self._changes, []
        return sorted(out, key=lambda c: c.t)

    def input_changed(self, signal: str, value: bool, t: float) -> None:
        self._changes.append(IoChange(signal, value, t))
