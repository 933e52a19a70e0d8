"""A simulated vibratory plate: a bulk container, a backlit rectangular plate,
and the actions an AnyFeeder-class feeder offers — dispense, feed forward/backward, flip,
purge — each moving the parts by stated physics (docs/plate-feeders.md, "Physics").

``PlateWorld`` is the belt ``World`` with the belts taken away: the parts on the plate
are kept where the world keeps the parts on its horizontal belt (``on_horizontal``, in the
same frame, the belt never moving), so the robot's grips, the touching of parts, the
rendering of frames and the accounting by identity are the belt cell's own code. The
hopper is the bulk container; a purge returns parts to it through ``return``. Nothing here
is shown to the locator: it sees rendered pixels only.

Every action takes ``reps * rep_s`` of motion and ``settle_s`` of settling; the parts move
at the action's end (the camera is never triggered while the plate moves: the trees look
only after the action's job ends).
"""

from __future__ import annotations

import heapq
import math
from collections.abc import Callable

import cv2
import numpy as np

from feeder_bt.core.clock import SimClock
from feeder_bt.core.errors import HalError
from feeder_bt.core.geometry import circumradius, is_convex, outer, place_outline, wrap_deg
from feeder_bt.core.jobs import DoneJob, Job
from feeder_bt.core.model import CellSpec, Scenario
from feeder_bt.hal.interfaces import PlateStatus
from feeder_bt.robot.model import RobotModel, with_speed_factor
from feeder_bt.sim.accounting import SimPart
from feeder_bt.sim.devices import (
    SimCamera,
    SimConveyor,
    SimHal,
    SimIO,
    SimRobot,
    SimRobotPosition,
    TimedJob,
)
from feeder_bt.sim.landing import TOUCH_GAP_MM, _grown
from feeder_bt.sim.world import World

PURGE_TRANSIT_S = 1.0      # a purged part falls back into the bulk container in this long


class PlateWorld(World):
    """The ground truth of a plate cell: parts in the bulk container, on the plate, held,
    placed (and back in the bulk after ``RECYCLE_S``), or falling back after a purge."""

    def __init__(self, scenario: Scenario, cell: CellSpec, clock: SimClock, seed: int) -> None:
        super().__init__(scenario, cell, clock, seed)
        self.plate = cell.plate
        self.rng_plate = np.random.default_rng([seed, 31])
        self.next_release = math.inf          # no incline: only a dispense takes parts
        (self.x_lo, self.y_lo), (length, width) = self.plate.origin_mm, self.plate.size_mm
        self.x_hi, self.y_hi = self.x_lo + length, self.y_lo + width
        self._inradii: dict[tuple[str, str], float] = {}

    # the belt's own events are gone: the plate never moves the frame, the incline never
    # releases; what remains is the timed events, the purge's return, the recycling
    def _draw_gap(self, at: float) -> float:
        return math.inf

    def _next_event(self) -> tuple[float | None, Callable[..., None], object]:
        cands: list[tuple[float, Callable[..., None]]] = []
        if self._timed:
            cands.append((self._timed[0][0], self._run_timed))
        if self.returning:
            cands.append((self.returning[0][0], self._arrive_hopper))
        if self.placed:
            cands.append((self.placed[0][0], self._recycle))
        if not cands:
            return None, _noop, None
        t, fn = min(cands, key=lambda c: c[0])    # stable: the first of equal times
        return t, fn, None

    # ------------------------------------------------------------------ physics
    def _bulk_fill(self) -> float:
        return min(1.0, len(self.hopper) / max(1, self.plate.bulk_nominal))

    def do_dispense(self, reps: int) -> int:
        """A Poisson number of parts (mean ``dispense_per_rep`` a repetition, less as the
        bulk empties) drop onto the rear band of the plate, each in a pose drawn from its
        type's stable-pose probabilities, at a random angle."""
        rng = self.rng_plate
        n = min(len(self.hopper), int(rng.poisson(self.plate.dispense_per_rep * reps
                                                    * self._bulk_fill())))
        for _ in range(n):
            part = self.parts[self.hopper.popleft()]
            self._relocate(part, "hopper", "horizontal")
            self._new_pose(part)
            r = part.radius
            part.x0 = float(rng.uniform(self.x_lo + r, min(self.x_lo + self.plate.
                                                           dispense_band_mm, self.x_hi - r)))
            part.y = float(rng.uniform(self.y_lo + r, self.y_hi - r))
            part.settle_end = -math.inf
            self.on_horizontal[part.id] = part
            self.counts["released"] += 1
            self.counts["landed"] += 1
        self.counts["dispensed"] += n
        return n

    def _new_pose(self, part: SimPart) -> None:
        names, cdf = self._pose_table(part.type)
        part.pose = names[int(cdf.searchsorted(self.rng_plate.random(), side="right"))]
        part.pickable = self.scenario.parts[part.type].poses[part.pose].pickable
        part.outline = self.outline(part.type, part.pose)
        part.radius = circumradius(part.outline)
        part.angle = float(self.rng_plate.uniform(-180.0, 180.0))

    def do_feed(self, direction: int, reps: int) -> None:
        """Each part moves ``feed_mm_per_rep`` a repetition (spread ``feed_cv``) in the
        direction, wanders sideways and turns a little; the end walls stop it, so parts
        fed long enough gather against a wall."""
        p, rng = self.plate, self.rng_plate
        for part in self._in_order():
            step = max(0.0, 1.0 + p.feed_cv * float(rng.standard_normal()))
            part.x0 += direction * p.feed_mm_per_rep * reps * step
            part.y += p.feed_jitter_mm * math.sqrt(reps) * float(rng.standard_normal())
            part.angle = wrap_deg(part.angle + p.feed_turn_deg * math.sqrt(reps)
                                  * float(rng.standard_normal()))
            self._keep_on(part)

    def do_flip(self, reps: int, direction: int = 0) -> None:
        """Each repetition throws each part up: with ``flip_prob`` it lands in a pose drawn
        anew (its stable-pose probabilities) at a new angle, thrown ``flip_scatter_mm``;
        a flip with a direction also feeds one repetition that way (x=3 / x=4)."""
        p, rng = self.plate, self.rng_plate
        for _ in range(reps):
            for part in self._in_order():
                if rng.random() < p.flip_prob:
                    self._new_pose(part)
                part.x0 += p.flip_scatter_mm * float(rng.standard_normal())
                part.y += p.flip_scatter_mm * float(rng.standard_normal())
                self._keep_on(part)
        if direction:
            self.do_feed(direction, 1)

    def do_purge(self, reps: int, t: float) -> int:
        """The plate carries its parts back ``purge_mm_per_rep`` a repetition; those past
        the rear edge fall back into the bulk container (through ``return``)."""
        p, rng = self.plate, self.rng_plate
        back = 0
        for part in self._in_order():
            # each repetition's throw drawn anew: a long purge carries every part off
            steps = np.maximum(0.0, 1.0 + p.feed_cv * rng.standard_normal(reps))
            part.x0 -= p.purge_mm_per_rep * float(steps.sum())
            if part.x0 < self.x_lo + 0.5 * part.radius:
                self.on_horizontal.pop(part.id)
                self._untouch(part)
                self._relocate(part, "horizontal", "return")
                heapq.heappush(self.returning, (t + PURGE_TRANSIT_S, part.id))
                back += 1
            else:
                self._keep_on(part)
        self.counts["purged"] += back
        return back

    def _in_order(self) -> list[SimPart]:
        return sorted(self.on_horizontal.values(), key=lambda q: q.id)

    def _keep_on(self, part: SimPart) -> None:
        r = part.radius
        part.x0 = min(max(part.x0, self.x_lo + r), self.x_hi - r)
        part.y = min(max(part.y, self.y_lo + r), self.y_hi - r)

    def settle_all(self, t: float) -> None:
        """The parts are at rest: which touch (and so cannot be gripped alone)?"""
        parts = self._in_order()
        for part in parts:
            part.touching.clear()
            part.settle_end = -math.inf
        if len(parts) < 2:
            return
        # pairs by their circles first (numpy): apart beyond the circumcircles never touch,
        # overlapping inscribed circles always do; only the rest go to the outlines
        xy = np.array([(q.x0, q.y) for q in parts])
        rc = np.array([q.radius for q in parts])
        ri = np.array([self._inradius(q) for q in parts])
        d = np.hypot(*(xy[:, None, :] - xy[None, :, :]).transpose(2, 0, 1))
        near = np.triu(d <= rc[:, None] + rc[None, :] + TOUCH_GAP_MM, 1)
        sure = d < ri[:, None] + ri[None, :]
        grown: dict[int, np.ndarray | None] = {}      # each part's grown outline, once

        def polygon(k: int) -> np.ndarray | None:
            if k not in grown:
                q = parts[k]
                ring = outer(q.outline)
                grown[k] = (_grown(place_outline(ring, q.x0, q.y, q.angle), (q.x0, q.y),
                                   TOUCH_GAP_MM / 2).astype(np.float32)
                            if is_convex(ring) else None)
            return grown[k]

        for i, j in zip(*np.nonzero(near), strict=True):
            a, b = parts[i], parts[j]
            if not sure[i, j]:
                pa, pb = polygon(i), polygon(j)
                if pa is not None and pb is not None:      # convex: the belt's own test
                    if cv2.intersectConvexConvex(pa, pb)[0] <= 0.0:
                        continue
                elif not self._touch(a, b, t):
                    continue
            a.touching.add(b.id)
            b.touching.add(a.id)

    def _inradius(self, part: SimPart) -> float:
        """The largest circle about the part's centre inside its outer outline."""
        key = (part.type, part.pose)
        r = self._inradii.get(key)
        if r is None:
            ring = outer(part.outline).astype(np.float32).reshape(-1, 1, 2)
            r = self._inradii[key] = max(0.0, float(cv2.pointPolygonTest(ring, (0.0, 0.0),
                                                                          True)))
        return r

    def plate_truth(self) -> dict[str, int]:
        """Counts for tests and the dashboard (never the locator)."""
        on = list(self.on_horizontal.values())
        return {"bulk": len(self.hopper), "plate": len(on),
                "pickable": sum(p.pickable and p.singulated for p in on)}


class SimPlateFeeder:
    """The ``PlateFeeder`` of the simulated cell: one action at a time, none before
    ``init`` (as the AnyFeeder refuses: m16/m26, m11 busy)."""

    def __init__(self, world: PlateWorld) -> None:
        self.world = world
        self.initialised = False
        self.busy: Job | None = None

    def _run(self, name: str, reps: int, apply: Callable[[float], object],
             needs_init: bool = True, duration: float | None = None) -> Job:
        if self.busy is not None and not self.busy.done:
            return DoneJob(name, error=HalError(f"plate busy with {self.busy.name}; "
                                                f"{name} refused"))
        if needs_init and not self.initialised:
            return DoneJob(name, error=HalError(f"plate not initialised; {name} refused"))
        w = self.world
        p = w.plate
        if duration is None:
            duration = reps * p.rep_s + p.settle_s
        job = TimedJob(name, w)
        self.busy = job

        def done(t: float) -> None:
            result = apply(t)
            w.settle_all(t)
            job.succeed(result)

        return job.at(w.now() + duration, done)

    def init(self) -> Job:
        def homed(t: float) -> None:
            self.initialised = True
        return self._run("plate.init", 0, homed, needs_init=False,
                         duration=self.world.plate.init_s)

    def reset(self) -> Job:
        return DoneJob("plate.reset")

    def dispense(self, reps: int) -> Job:
        return self._run("plate.dispense", reps, lambda t: self.world.do_dispense(reps))

    def feed(self, direction: int, reps: int) -> Job:
        return self._run(f"plate.feed({direction:+d})", reps,
                         lambda t: self.world.do_feed(1 if direction >= 0 else -1, reps))

    def flip(self, reps: int, direction: int = 0) -> Job:
        return self._run("plate.flip", reps + (1 if direction else 0),
                         lambda t: self.world.do_flip(reps, direction))

    def purge(self, reps: int) -> Job:
        return self._run("plate.purge", reps, lambda t: self.world.do_purge(reps, t))

    def status(self) -> PlateStatus:
        return PlateStatus(self.initialised, self.busy is not None and not self.busy.done)


class PlateFrame(SimConveyor):
    """The plate's frame where a belt cell has its horizontal belt: the leaves that read a
    belt's count (the encoder sync, a part's position now) read a constant; anything that
    would move it is refused, so no belt leaf can move the plate's parts by mistake."""

    def _no_belt(self, what: str) -> Job:
        return DoneJob(f"{self.name}.{what}", error=HalError(
            f"a plate cell has no belt: {self.name}.{what} refused"))

    def set_speed(self, mm_s: float) -> Job:
        return DoneJob(f"{self.name}.set_speed") if mm_s == 0 else self._no_belt("set_speed")

    def move(self, distance_mm: float, mm_s: float) -> Job:
        return self._no_belt("move")

    def shake(self, amplitude_mm: float, cycles: int) -> Job:
        return self._no_belt("shake")

    def stop(self) -> Job:
        return DoneJob(f"{self.name}.stop")


class PlateSimHal(SimHal):
    """The simulated plate cell behind the HAL: the plate, the robot, the camera, I/O.
    ``conveyors`` holds the plate's frame only (a conveyor that is never moved), so the
    leaves that read a belt's count read a constant."""

    def changeover(self, scenario: Scenario) -> None:
        fresh = make_plate_sim_hal(scenario, self.world.cell, self.world.clock, self.world.seed)
        fresh.world.listeners = self.world.listeners
        fresh.world.problems = self.world.problems
        self.camera.close()
        self.__dict__.update(fresh.__dict__)


def make_plate_sim_hal(scenario: Scenario, cell: CellSpec, clock: SimClock,
                       seed: int) -> PlateSimHal:
    world = PlateWorld(scenario, cell, clock, seed)
    if cell.robot.sim_speed_factor != 1.0:
        world.robot_model = RobotModel(with_speed_factor(cell.robot, cell.robot.sim_speed_factor))
    hal = PlateSimHal(
        conveyors={"horizontal": PlateFrame("horizontal", world.horizontal, world)},
        robot=SimRobot(world), robot_position=SimRobotPosition(world),
        camera=SimCamera(world, cell, seed), io=SimIO(world), kind="sim",
        plate=SimPlateFeeder(world))
    hal.world = world
    return hal


def _noop(t: float) -> None:
    pass
