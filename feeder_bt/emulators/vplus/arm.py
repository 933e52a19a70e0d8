"""The robot arm under V+: motions in its own world frame, bound to the plant.

Forward processing (V+ Language User's Guide, chapter 8, "Motion Control Instructions"):
a motion instruction starts the motion and the program goes on; the next motion
instruction waits until the arm is free, ``BREAK`` waits for the motion to end, ``DELAY``
is itself a motion during which the arm holds still (or keeps tracking: NOT CONFIRMED).
``BRAKE``, from any task, ends the motion in progress where the arm is (User's Guide v17
p. 33).

Times come from the plant's arm (``World.robot_model``, a SCARA: ``feeder_bt.robot.scara``, the
one the simulated robot uses): each motion is joint-interpolated, joints 1, 2 and Z each a
trapezoid under its own limits, the slowest setting the time, at the program speed times
the operator's override, times the simulator's per-move time factor. A motion the program
reached while the previous one still ran follows on without a stop (continuous path,
User's Guide ch. 8): its acceleration overlaps the previous motion's deceleration; after a
BREAK, a DELAY or a BRAKE the next starts from rest. A target
outside the annulus ``inner_reach_mm .. reach_mm`` about the base (robot world) is refused
with -610 *Location out of range* before the arm moves; a tracked location that leaves
the reach or the belt's window stops the arm and calls the window program.

The arm's base truly sits at ``true_base`` in the cell frame: every judgement the plant
makes (a grip, a release, where the robot is drawn) uses the arm's true cell-frame pose,
so a program that composes its poses in a wrong frame misses, as a real arm would.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from feeder_bt.emulators.vplus.task import VError
from feeder_bt.emulators.vplus.trans import BeltLoc, Trans

if TYPE_CHECKING:
    from feeder_bt.emulators.vplus.runtime import Runtime

ERR_POWER_OFF = -604
ERR_RANGE = -610
ERR_STALLED = -1007
SERVO_FAULT_S = 0.25      # an injected collision: the arm runs into something this soon
REACH_WAIT_S = 3.0        # longest the arm waits for a tracked location to come into reach


@dataclass
class Motion:
    kind: str
    start: Trans          # robot world, where the motion began
    target: Any           # Trans or BeltLoc
    t0: float
    t1: float


class Arm:
    """One robot (task 0 moves it; any task may BRAKE it)."""

    def __init__(self, rt: Runtime, true_base: Trans, start_world: Trans) -> None:
        self.rt = rt
        self.true_base = true_base
        self.loc: Any = start_world            # where the arm is, or is tracking
        self.motion: Motion | None = None
        self.power = True
        self.speed = 100.0                     # program speed (SPEED ... ALWAYS)
        self.fault_at: float | None = None     # an injected servo fault's time
        self.fault_armed = False               # the next motion runs into something
        self.log: list[tuple[str, tuple[float, float, float]]] = []   # (kind, cell xyz)
        self.owner = None                      # the task that moves the arm (task 0)
        self.ramp_s = 0.0                      # the last motion's deceleration (0: at rest)

    # ------------------------------------------------------------ where
    def _at(self, target: Any, count: int) -> Trans:
        return target.at(count) if isinstance(target, BeltLoc) else target

    def here(self, t: float | None = None) -> Trans:
        t = self.rt.now() if t is None else t
        count = self.rt.track_count()
        m = self.motion
        if m is None or t >= m.t1:
            return self._at(self.loc, count)
        end = self._at(m.target, count)
        f = (t - m.t0) / max(m.t1 - m.t0, 1e-9)
        f = f * f * (3.0 - 2.0 * f)            # smooth: starts and ends at rest
        out = Trans((end if f > 0.5 else m.start).m.copy())
        out.m[:3, 3] = m.start.m[:3, 3] + f * (end.m[:3, 3] - m.start.m[:3, 3])
        return out

    def cell_pose(self, t: float | None = None) -> tuple[float, float, float, float]:
        """The arm's true pose in the cell frame: x, y, z, the gripper's turn (deg)."""
        x, y, z, _, pitch, roll = (self.true_base @ self.here(t)).decompose()
        return x, y, z, roll

    def busy(self, t: float | None = None) -> bool:
        m = self.motion
        return m is not None and (self.rt.now() if t is None else t) < m.t1

    # ------------------------------------------------------------ motions
    def in_reach(self, loc: Trans) -> bool:
        x, y, _ = loc.xyz
        spec = self.rt.robot_spec()
        r = math.hypot(x, y)
        return spec.inner_reach_mm <= r <= spec.reach_mm

    def start(self, kind: str, target: Any, blend: bool = False) -> None:
        """Start a motion now (the caller waited until the arm was free)."""
        if not self.power:
            raise VError(ERR_POWER_OFF, "*Robot power off*")
        now = self.rt.now()
        prev = self.loc
        before = self.ramp_s if blend else 0.0
        ramp = 0.0
        start = self.here(now)
        self.loc = start
        self.motion = None
        duration = 0.0
        if kind == "delay":                    # hold still, or keep tracking the belt
            duration = float(target)
            target = prev if isinstance(prev, BeltLoc) else start
            self.ramp_s = 0.0
        else:
            for _ in range(4):                 # intercept a tracked target
                end = self._at(target, self.rt.track_count(now + duration))
                duration, ramp = self._time(start, end, before)
            end = self._at(target, self.rt.track_count(now + duration))
            if not self.in_reach(end) and isinstance(target, BeltLoc):
                duration, end = self._wait_for_reach(target, now, duration, end)
            if not self.in_reach(end):         # where the arm meets the target
                raise VError(ERR_RANGE, "*Location out of range*")
            self.ramp_s = ramp
            if isinstance(target, BeltLoc) and kind == "moves":
                duration += self.rt.robot_spec().track_settle_s
            self.log.append((kind, tuple((self.true_base @ end).xyz)))  # type: ignore[arg-type]
        self.motion = Motion(kind, start, target, now, now + duration)
        self.loc = target
        if self.fault_armed and kind != "delay":
            self.fault_armed = False
            self.fault_at = now + min(SERVO_FAULT_S, max(duration * 0.5, 0.0))

    def _wait_for_reach(self, target: BeltLoc, now: float, duration: float,
                        end: Trans) -> tuple[float, Trans]:
        """A tracked location still upstream of the reach: the arm meets it where it comes
        into reach, later than it could be there (V+ belt tracking with the location
        upstream of the window: the robot waits for it; NOT CONFIRMED, BELT.MODE)."""
        t = now + duration
        while t < now + REACH_WAIT_S:
            t += 0.01
            loc = self._at(target, self.rt.track_count(t))
            if self.in_reach(loc):
                return t - now, loc
        return duration, end

    def _time(self, a: Trans, b: Trans, before: float = 0.0) -> tuple[float, float]:
        """(the motion's time, its deceleration's): the arm's joint-space time, less the
        overlap of its acceleration with the previous motion's deceleration ``before``."""
        world = self.rt.plant.world
        pct = max(self.speed, 1e-3) * world.speed_override_pct / 100.0
        t, ramp = world.robot_model.segment_time(a.xyz, b.xyz, pct)
        f = world.imperfect.time_factor()
        return f * (t - min(before, ramp)), f * ramp

    def brake(self) -> None:
        """BRAKE: the arm stops where it is; nothing more of this motion runs."""
        now = self.rt.now()
        self.ramp_s = 0.0
        if self.motion is not None and now < self.motion.t1:
            self.loc = self.here(now)
            self.motion = None
        elif isinstance(self.loc, BeltLoc):    # holding still on the belt: stop tracking
            self.loc = self.here(now)
            self.motion = None

    def set_location(self, world: Trans) -> None:
        """The arm is put somewhere without a program motion (the pendant)."""
        self.motion = None
        self.loc = world

    # ------------------------------------------------------------ servo loop
    def poll(self, estop: bool) -> None:
        """Every servo cycle: the e-stop, an injected fault, a tracked location."""
        now = self.rt.now()
        if estop and self.power:
            self.power = False
            if self.busy(now):
                self.brake()
                self._post(VError(ERR_POWER_OFF, "*Robot power off*"))
        if self.fault_at is not None and now >= self.fault_at:
            self.fault_at = None
            self.brake()
            self.power = False
            self._post(VError(ERR_STALLED, "*Motor stalled*"))
        if isinstance(self.loc, BeltLoc) and not self.busy(now):   # tracking, arrived
            bl = self.loc
            count = self.rt.track_count()
            past = bl.belt.window is not None and bl.belt_x(count) > bl.belt.window[1]
            if past or not self.in_reach(bl.at(count)):
                self.brake()
                if bl.belt.window_program:
                    self._post(bl.belt.window_program)
                else:
                    self._post(VError(ERR_RANGE, "*Location out of range*"))

    def _post(self, item: Any) -> None:
        if self.owner is not None:
            self.owner.post(item)
