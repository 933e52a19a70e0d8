"""Fault injection into the simulated cell, from a fault plan (``docs/faults.md``).

``inject_faults`` wraps the devices of a ``SimHal`` in place with ones that keep the same
interfaces but fail the way real hardware does: a servo time-out part-way through a pick
that leaves the arm without power, a controller link that drops for a few seconds, a grab
with no image, a belt that stalls, a grip that misses, an e-stop pressed and released.
The trees cannot tell an injected fault from a real one; the injector counts and logs
each one so a run's report can match every injected fault against the trees' recoveries.

Timed faults are events on the world's own queue (``World.schedule``), so they happen at
exact virtual times however the world is stepped, and the fast ticker wakes for them. The
draws come from the injector's own generators (one per kind), seeded from the plan's
seed and the run's, so a run is repeatable and the world's random stream is untouched.
No part is ever moved by a fault: a failed pick leaves its part on the belt, a failed
place leaves it in the gripper, and the world's accounting check runs on every step.

A dropped robot link loses the *reply*, not the motion: the controller finishes a pick or
place it has started (as a V+ server task does when its socket breaks), so a part may be
gripped or placed while the cell hears nothing. The cell must ask (``Robot.held``).
Scripted link cuts can strike at a chosen step of the next pick-and-place (``phase``).

The injector decides when each fault happens; the wrapped devices (below it) say how each
device shows it.
"""

from __future__ import annotations

import itertools
from collections import Counter
from collections.abc import Callable
from typing import Any

import numpy as np

from feeder_bt.config.faults import FAULT_KINDS, FaultPlanSpec, FaultRate, ScriptedFault
from feeder_bt.core.errors import (
    CommsLost,
    ConfigError,
    ConveyorFault,
    FeederError,
    GrabFailed,
    HalError,
    MissedGrab,
    ServoTimeout,
)
from feeder_bt.core.jobs import DoneJob, Job, JobState
from feeder_bt.core.model import CellSpec
from feeder_bt.hal.camera.latched import grab_timeout_s
from feeder_bt.hal.interfaces import IoChange, PickTarget, Pose, watchdog_stopped
from feeder_bt.sim.devices import SimHal, TimedJob
from feeder_bt.sim.world import World

# ----------------------------------------------------------------------
# The simulated cell's devices as a fault plan makes them fail (``faults.py``).
#
# Each wraps one device of a ``SimHal`` and keeps its interface: calls on a link that is down
# fail at once, reads return what the controller last sent, and jobs in flight end with the
# fault. The robot's replies come through ``ReplyJob``: a dropped link loses the *reply*, not
# the motion, which goes on in the world to its end. Anything a wrapper does not override
# goes to the wrapped device. The ``FaultInjector`` decides when; these say how each device
# shows it.

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
    def freeze(self, t: float) -> None:
        """The link dropped at ``t``: remember the reads (the belt's motion itself is not
        touched)."""
        self._frozen = (self._inner.speed(), self._inj.world.galil_count(t))

    def fail_in_flight(self, err: HalError) -> bool:
        """The jobs in flight fail with the lost link. True if any did."""
        return self._fail_jobs(err)

    def jammed(self, err: HalError) -> bool:
        """The belt stalled: ``fault()`` reports it, motions in flight end with it (their
        planned profile is gone); distance notifications wait for the belt to move."""
        self.jam = err
        return self._fail_jobs(err, lambda job: isinstance(job, TimedJob))


class FaultyPlate(_Tracking):
    """The plate feeder on its serial line: while the line is down an action is not sent
    (at once, or after the driver's time-out on a silent line), and the reply of an action
    in flight is lost while the plate goes on to its end, as the AnyFeeder does; asked
    again meanwhile, it answers busy."""

    def _action(self, name: str, *args: Any) -> Job:
        refused = self._inj.refused("plate", f"plate.{name}")
        if refused is not None:
            return refused
        job = getattr(self._inner, name)(*args)
        return job if job.done else self._track(ReplyJob(job))

    def init(self) -> Job:
        return self._action("init")

    def reset(self) -> Job:
        return self._action("reset")

    def dispense(self, reps: int) -> Job:
        return self._action("dispense", reps)

    def feed(self, direction: int, reps: int) -> Job:
        return self._action("feed", direction, reps)

    def flip(self, reps: int, direction: int = 0) -> Job:
        return self._action("flip", reps, direction)

    def purge(self, reps: int) -> Job:
        return self._action("purge", reps)

    def fail_in_flight(self, err: HalError) -> bool:
        return self._fail_jobs(err)


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


__all__ = [
    "POWER_OFF", "SERVO_FRACTION", "FaultInjector", "FaultyCamera", "FaultyConveyor",
    "FaultyIO", "FaultyRobot", "FaultyRobotPosition", "ReplyJob", "inject_faults",
]

SERVO_FRACTION = 0.5            # a servo time-out stops the pick this far into its duration
_MASK64 = (1 << 64) - 1


def plan_rng(plan_seed: int, seed: int, stream: int) -> np.random.Generator:
    """A plan's own random stream: from the plan's seed, the run's and a stream number, so
    a plan never draws from the world's generator (nor one plan's kind from another's)."""
    return np.random.default_rng([plan_seed & _MASK64, seed & _MASK64, stream])


_LINKS = ("galil", "adept", "camera", "plate")
_LINK_NAMES = {"galil": "conveyor controller (Galil)", "adept": "robot controller (Adept)",
               "camera": "camera", "plate": "plate feeder (AnyFeeder)"}


class FaultInjector:
    """Carries out a fault plan on one simulated cell; ``injected`` and ``log`` say what it
    did. Create it with ``inject_faults``."""

    def __init__(self, hal: SimHal, plan: FaultPlanSpec, seed: int,
                 drivers: CellSpec | None = None) -> None:
        self.plan = plan
        self.seed = seed
        #: the cell file the controller's drivers are set from: their time-outs and the
        #: watchdog period they give the card are its figures, not the world's truth
        self.drivers = drivers
        #: every fault actually injected, by plan kind (``FAULT_KINDS``)
        self.injected: Counter[str] = Counter()
        #: one entry per injected fault: ``t``, ``kind``, ``device``, ``detail`` and ``seen``
        #: (whether any caller met it: a refused call, a failed job, a read of ``fault()``)
        self.log: list[dict[str, Any]] = []
        self.power_on = True
        self.down: dict[str, bool] = dict.fromkeys(_LINKS, False)
        self.silent: dict[str, bool] = dict.fromkeys(_LINKS, False)
        self.estop_presses = 0
        self.watchdog_stops = 0                   # outages the card's watchdog ended
        self._rngs = {kind: plan_rng(plan.seed, seed, i) for i, kind in enumerate(FAULT_KINDS)}
        self._armed: Counter[str] = Counter()     # scripted per-pick/per-frame faults waiting
        self._cuts: list[ScriptedFault] = []      # scripted link cuts waiting for their step
        self._alternate = itertools.cycle(("galil", "adept"))
        self._outage_entry: dict[str, dict[str, Any]] = {}
        self._jam_entry: dict[str, Any] | None = None
        self._pending: dict[int, tuple[float, Callable[[float], None], int]] = {}
        self._keys = itertools.count()
        self.hal = hal
        self._check_cell(hal.world)             # before anything is wrapped
        self._attach(hal)
        self.t0 = self.world.now()
        self._schedule_plan()

    # ------------------------------------------------------------------ wiring
    def _attach(self, hal: SimHal) -> None:
        """Wrap the HAL's devices in place (again after a changeover's fresh devices)."""
        self.hal = hal
        self.world: World = hal.world
        self.robot = FaultyRobot(hal.robot, self)
        self.position = FaultyRobotPosition(hal.robot_position, self)
        self.camera = FaultyCamera(hal.camera, self)
        self.conveyors = {name: FaultyConveyor(c, self) for name, c in hal.conveyors.items()}
        self.io = FaultyIO(hal.io, self)
        hal.robot, hal.robot_position, hal.camera = self.robot, self.position, self.camera
        hal.conveyors, hal.io = dict(self.conveyors), self.io
        self.plate = FaultyPlate(hal.plate, self) if hal.plate is not None else None
        if self.plate is not None:
            hal.plate = self.plate
        hal.extras["fault_injector"] = self
        hal.changeover = self._changeover       # type: ignore[method-assign]

    def _changeover(self, scenario: Any) -> None:
        """A changeover builds a fresh world and devices: wrap those and move the plan's
        pending events onto the new world (the clock, and so the plan's times, go on)."""
        SimHal.changeover(self.hal, scenario)
        pending, self._pending = self._pending, {}
        self._attach(self.hal)
        if self.estop_presses:                  # still pressed: the fresh world's input too
            self.world.io["estop"] = True
        for t, fn, _ in sorted(pending.values(), key=lambda e: e[0]):
            self._at(t, fn)

    def _check_cell(self, world: World) -> None:
        plate = getattr(self.hal, "plate", None) is not None
        for kind, rate in self.plan.rates.items():
            if kind == "comms_lost" and rate.device == "plate" and not plate:
                raise ConfigError(f"the plan drops the plate's link but cell "
                                  f"{world.cell.name!r} has no plate feeder",
                                  file=str(self.plan.path), key=f"rates.{kind}.device")
        for i, sf in enumerate(self.plan.scripted):
            if sf.kind == "comms_lost" and sf.device == "plate" and not plate:
                raise ConfigError(f"the plan drops the plate's link but cell "
                                  f"{world.cell.name!r} has no plate feeder",
                                  file=str(self.plan.path), key=f"scripted[{i}].device")
            if sf.kind == "estop" and "estop" not in world.io:
                raise ConfigError(f"the plan presses an e-stop but cell {world.cell.name!r} "
                                  "has no 'estop' input (add one under io:)",
                                  file=str(self.plan.path), key=f"scripted[{i}].kind")

    def _at(self, t: float, fn: Callable[[float], None]) -> None:
        """Schedule a plan event on the world, remembered until it runs (for changeovers)."""
        key = next(self._keys)

        def run(now: float) -> None:
            self._pending.pop(key, None)
            fn(now)

        self._pending[key] = (t, fn, self.world.schedule(t, run))

    # ------------------------------------------------------------------ the plan
    def _schedule_plan(self) -> None:
        for kind, rate in self.plan.rates.items():
            unit, value = rate.rate()
            if unit == "per_hour" and value > 0:
                self._next_arrival(kind, rate, self.t0)
        for sf in self.plan.scripted:
            self._at(self.t0 + sf.at_s, lambda t, sf=sf: self._scripted(sf, t))

    def _next_arrival(self, kind: str, rate: FaultRate, after: float) -> None:
        """Poisson arrivals: exponential gaps of mean 3600 / per_hour seconds."""
        gap = float(self._rngs[kind].exponential(3600.0 / rate.per_hour))

        def arrive(t: float) -> None:
            self._fire(kind, t, rate.device, rate.outage_s, rate.counts, rate.link)
            self._next_arrival(kind, rate, t)

        self._at(after + gap, arrive)

    def _scripted(self, sf: ScriptedFault, t: float) -> None:
        if sf.kind in ("servo_timeout", "missed_grab", "grab_failed"):
            self._armed[sf.kind] += 1          # the next pick (or grab) gets it
        elif sf.kind == "comms_lost" and sf.phase is not None:
            self._cuts.append(sf)              # at that step of the next pick-and-place
        elif sf.kind == "estop":
            self._estop(t, sf.release_after_s)
        else:
            self._fire(sf.kind, t, sf.device, sf.outage_s, sf.counts, sf.link)

    def _fire(self, kind: str, t: float, device: str, outage_s: float,
              counts: int = 0, how: str = "refused") -> None:
        if kind == "comms_lost":
            self._drop(device if device != "alternate" else next(self._alternate), t, outage_s,
                       how=how)
        elif kind == "conveyor_jam":
            self._jam(t)
        elif kind == "encoder_slip":
            self.world.robot_slip += counts    # pulses the robot's counter gained (noise)
            self._record(t, kind, "adept", f"robot belt counter +{counts} counts")

    def _draw(self, kind: str) -> bool:
        """Whether this pick or frame gets a fault of ``kind`` (a scripted one first)."""
        rate = self.plan.rates.get(kind)
        hit = rate is not None and bool(self._rngs[kind].random() < rate.rate()[1])
        if self._armed[kind] > 0:
            self._armed[kind] -= 1
            return True
        return hit

    def _record(self, t: float, kind: str, device: str, detail: str,
                seen: bool = True) -> dict[str, Any]:
        entry = {"t": round(t, 6), "kind": kind, "device": device, "detail": detail,
                 "seen": seen}
        self.injected[kind] += 1
        self.log.append(entry)
        return entry

    @property
    def unseen(self) -> Counter[str]:
        """Injected faults nobody met (a link that came back before anything used it, a jam
        cleared by a command before ``fault()`` was read): the trees cannot count those."""
        return Counter(e["kind"] for e in self.log if not e["seen"])

    # ------------------------------------------------------------------ robot faults
    def on_pick(self, job: TimedJob, target: PickTarget) -> None:
        """A pick the robot accepted: maybe a servo time-out part-way, or a missed grab."""
        w = self.world
        servo = self._draw("servo_timeout")
        missed = self._draw("missed_grab")
        if not (servo or missed):
            return
        t0 = w.now()
        t_grip = _event_time(w, job.seq)
        if t_grip is None:
            return
        w.unschedule(job.seq)
        if servo:
            t_fail = t0 + SERVO_FRACTION * (t_grip - t0)
            job.seq = w.schedule(t_fail, lambda t: self._servo_fail(job, target, t))
        else:
            job.seq = w.schedule(t_grip, lambda t: self._missed(job, target, t))

    def _servo_fail(self, job: TimedJob, target: PickTarget, t: float) -> None:
        job.seq = None
        self.power_on = False
        self._record(t, "servo_timeout", "adept",
                     f"pick of part {target.part_id} stopped part-way; arm power off")
        _fail_timed(self.world, job, ServoTimeout(
            "servo time-out during the pick (motor stalled): arm power is off"))

    def _missed(self, job: TimedJob, target: PickTarget, t: float) -> None:
        job.seq = None
        cx, cy = self.world.commanded_xy(target, t)
        self.world.robot_pose = Pose(cx, cy, 0.0, target.angle_deg)   # it got there
        self._record(t, "missed_grab", "adept", f"no vacuum on part {target.part_id}")
        _fail_timed(self.world, job, MissedGrab(
            f"vacuum not made on part {target.part_id}: nothing held after the grip"))

    def on_recovered(self, job: Job) -> None:
        if job.ok:
            self.power_on = True

    # ------------------------------------------------------------------ links
    def cut(self, phase: str, t: float) -> bool:
        """A scripted link cut waiting for ``phase`` strikes now; True if it did."""
        sf = next((c for c in self._cuts if c.phase == phase), None)
        if sf is None:
            return False
        self._cuts.remove(sf)
        link = sf.device if sf.device != "alternate" else next(self._alternate)
        self._drop(link, t, sf.outage_s, phase, how=sf.link)
        return True

    def _drop(self, link: str, t: float, outage_s: float, phase: str | None = None,
              how: str = "refused") -> None:
        """The link goes down for ``outage_s``: calls fail at once (``refused``), or, on a
        ``silent`` link (a pulled cable), each waits out the driver's time-out first; the
        replies of jobs in flight are lost now (a robot motion itself goes on to its end)."""
        if self.down[link]:
            return                              # already down: not a second fault
        self.down[link] = True
        self.silent[link] = how == "silent"
        at = f" ({phase.replace('_', ' ')})" if phase else ""
        entry = self._record(t, "comms_lost", link,
                             f"{_LINK_NAMES[link]} connection lost for {outage_s:g} s{at}",
                             seen=False)
        self._outage_entry[link] = entry
        err = CommsLost(f"{_LINK_NAMES[link]}: connection lost")
        if link == "adept":
            self.position.freeze(t)
        elif link == "galil":
            for conv in self.conveyors.values():
                conv.freeze(t)
            watchdog_s = (self.drivers or self.world.cell).galil.watchdog_s
            if 0 < watchdog_s < outage_s:
                self._at(t + watchdog_s, lambda now: self._watchdog(now, entry, watchdog_s))

        def fail_in_flight(now: float) -> None:
            """The jobs in flight learn of it: at once on a refused link, after the
            driver's time-out on a silent one (nothing answers them meanwhile)."""
            if link == "adept":
                lost = self.robot.lose_replies(err)
            elif link == "galil":
                lost = any([conv.fail_in_flight(err) for conv in self.conveyors.values()])
            elif link == "plate":
                lost = self.plate is not None and self.plate.fail_in_flight(err)
            else:
                lost = self.camera.fail_in_flight(err)
            if lost:
                entry["seen"] = True

        if how == "silent":
            self._at(t + self._timeout_s(link), fail_in_flight)
        else:
            fail_in_flight(t)
        self._at(t + outage_s, lambda now: self._restore(link))

    def _watchdog(self, t: float, outage: dict[str, Any], watchdog_s: float) -> None:
        """The host has been silent for ``galil.watchdog_s``: the card's ``#WDOG``
        (galil_programs/monitor.dmc) stops every axis, as on a real card or the emulator;
        each conveyor's ``fault()`` says so once the link is back."""
        if self._outage_entry.get("galil") is not outage:
            return                              # the link came back in time
        self.watchdog_stops += 1
        outage["detail"] += f"; the card's watchdog stopped the belts after {watchdog_s:g} s"
        for name, conv in self.conveyors.items():
            getattr(self.world, name).jog(t, 0.0)
            conv.watchdog = watchdog_stopped(name, watchdog_s)

    def _restore(self, link: str) -> None:
        self.down[link] = False
        self._outage_entry.pop(link, None)

    def is_down(self, link: str) -> bool:
        self.world.now()                        # events due by now (a restore) happen first
        return self.down[link]

    def refused(self, link: str, name: str) -> Job | None:
        """A call on a link that is down fails at once (and the outage was met)."""
        if not self.is_down(link):
            return None
        entry = self._outage_entry.get(link)
        if entry is not None:
            entry["seen"] = True
        err = CommsLost(f"{_LINK_NAMES[link]}: connection lost; {name} not sent")
        if not self.silent[link]:
            return DoneJob(name, error=err)
        # a pulled cable: nothing answers, and the driver learns it only from its time-out
        job = Job(name)
        self._at(self.world.now() + self._timeout_s(link),
                 lambda now: None if job.done else job.fail(err))
        return job

    def _timeout_s(self, link: str) -> float:
        """How long the link's driver waits for a reply before it gives the link up (the
        controller's cell file's figure)."""
        cell = self.drivers or self.world.cell
        if link == "galil":
            return cell.galil.timeout_s
        if link == "adept":
            return cell.adept.timeout_s
        if link == "plate":
            return cell.plate.timeout_s
        return grab_timeout_s(cell.camera)     # the camera driver's own bound

    # ------------------------------------------------------------------ conveyor, e-stop
    def _jam(self, t: float) -> None:
        """The horizontal belt stalls: it stops, and ``fault()`` says so until the next
        motion command. A belt that is not moving cannot stall: nothing is injected."""
        conv = self.conveyors.get("horizontal")
        axis = self.world.horizontal
        if conv is None or (abs(axis.vel(t)) < 1e-6 and axis.commanded == 0.0):
            return
        axis.jog(t, 0.0)
        err = ConveyorFault("horizontal conveyor stalled")
        self._jam_entry = self._record(t, "conveyor_jam", "galil",
                                       "horizontal belt stalled and stopped", seen=False)
        if conv.jammed(err):
            self._jam_entry["seen"] = True

    def jam_read(self) -> None:
        if self._jam_entry is not None:
            self._jam_entry["seen"] = True

    def jam_cleared(self) -> None:
        self._jam_entry = None

    def _estop(self, t: float, release_after_s: float) -> None:
        self.estop_presses += 1
        self._record(t, "estop", "io", f"e-stop pressed for {release_after_s:g} s")
        self._set_estop(t, True)
        self._at(t + release_after_s, self._release_estop)

    def _release_estop(self, t: float) -> None:
        self.estop_presses = max(0, self.estop_presses - 1)
        if self.estop_presses == 0:
            self._set_estop(t, False)

    def _set_estop(self, t: float, value: bool) -> None:
        if self.world.io.get("estop") != value:
            self.world.io["estop"] = value
            self.io.input_changed("estop", value, t)


def inject_faults(hal: SimHal, plan: FaultPlanSpec, seed: int | None = None,
                  drivers: CellSpec | None = None) -> FaultInjector:
    """Wrap the simulated cell's devices so they fail as ``plan`` says; ``seed`` is the
    run's seed (default: the world's), mixed with ``plan.seed`` for the fault draws;
    ``drivers`` the cell file the controller reads (default: the world's cell), whose
    drivers' time-outs a silent link is waited out by.

    Plan times count from now (the start of the run). Only the simulated cell takes a
    plan: the emulators have their own (``feeder_bt.emulators.faults``)."""
    if not isinstance(hal, SimHal):
        raise FeederError(f"fault plans are injected into the simulated cell only (--hal sim), "
                          f"not a {getattr(hal, 'kind', type(hal).__name__)} cell")
    if "fault_injector" in hal.extras:
        raise FeederError("this simulated cell already has a fault plan")
    return FaultInjector(hal, plan, hal.world.seed if seed is None else seed, drivers)
