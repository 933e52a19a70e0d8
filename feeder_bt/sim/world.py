"""The simulated feeder: hopper, inclined and horizontal conveyors, return conveyor, robot.

A discrete-event world on virtual time. Belt motion is analytic (``Axis``), so every event
— a part leaving the hopper, landing on the horizontal belt, falling off its end, a grip —
happens at an exact virtual time that does not depend on how often the world is stepped.

Honesty: the world knows where every part truly is; it hands the camera outlines to
render into pixels and judges each grip against the truth. Nothing here is shown to the
locator.

``World`` is one object made of parts kept in their own modules by concept: the event
queue and the part flow hopper → incline → belt → return (here), the parts' accounting by
identity (``accounting.py``: every part in exactly one place, audited), landing, resting
and touching on the belt (``landing.py``) and the robot's grips judged against the truth
(``grips.py``). Their constants and ``SimPart`` are importable from here too.
"""

from __future__ import annotations

import heapq
import itertools
import math
from collections import Counter, deque
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from feeder_bt.core.clock import EPS, SimClock
from feeder_bt.core.encoder import wrap
from feeder_bt.core.geometry import place_outline
from feeder_bt.core.jobs import Job
from feeder_bt.core.model import CellSpec, Scenario
from feeder_bt.hal.interfaces import Pose
from feeder_bt.robot.scara import world_arm
from feeder_bt.sim.accounting import AUDIT_EVERY, PLACES, PartAccounting, SimPart
from feeder_bt.sim.axis import Axis
from feeder_bt.sim.grips import PLACE_TOL_MM, RECYCLE_S, RobotGrips
from feeder_bt.sim.imperfect import Imperfections
from feeder_bt.sim.landing import EDGE_MARGIN_MM, LAND_X_MM, TOUCH_GAP_MM, Landing
from feeder_bt.sim.passlog import PassLog
from feeder_bt.sim.slip import BeltSlip

__all__ = [
    "AUDIT_EVERY", "EDGE_MARGIN_MM", "LAND_X_MM", "PLACES", "PLACE_TOL_MM", "RECYCLE_S",
    "TOUCH_GAP_MM", "Notification", "SimPart", "World",
]

#: belt samples the robot controller averages the belt's speed over for tracking (the
#: ``vavg`` of DEFBELT in vplus/a_server.v2)
TRACK_VAVG = 16


@dataclass
class Notification:
    axis: Axis
    target: float
    job: Job
    hinted_version: int = -1


class World(PartAccounting, Landing, RobotGrips, BeltSlip):
    """Ground truth of the simulated cell, advanced by ``step(now)``."""

    #: pulses the robot controller's belt counter gained or lost (an ``encoder_slip``
    #: fault): the robot tracks the belt by its own counter, so a pick lands this far off
    robot_slip: int = 0

    def __init__(self, scenario: Scenario, cell: CellSpec, clock: SimClock, seed: int) -> None:
        self.scenario, self.cell, self.clock, self.seed = scenario, cell, clock, seed
        self.rng = np.random.default_rng(seed)
        hc, ic = cell.conveyors["horizontal"], cell.conveyors["incline"]
        self.horizontal = Axis(hc.accel_mm_s2, hc.max_mm_s)
        self.incline = Axis(ic.accel_mm_s2, ic.max_mm_s)
        self.h_len, self.h_width, self.i_len = hc.length_mm, hc.width_mm, ic.length_mm
        self.cpm = cell.encoder.counts_per_mm
        # the arm as it really moves: a SCARA (feeder_bt.robot.scara), sim_speed_factor times a
        # Cobra 600; the trees see only the cell's Cartesian description
        self.robot_model = world_arm(cell.robot, cell.robot.sim_speed_factor, cell.sim)
        # every pass along the belt and every pick, for the report's robot bounds
        self.passlog = PassLog(clock.now(), 0.0)
        self.imperfect = Imperfections(cell.sim, self.cpm, cell.robot.grip_tolerance_mm, seed)
        self._last_landed: int | None = None
        self.t = clock.now()

        # where the parts are
        self.parts: dict[int, SimPart] = {}
        self.hopper: deque[int] = deque()
        self.on_incline: deque[int] = deque()
        self.on_horizontal: dict[int, SimPart] = {}
        self.returning: list[tuple[float, int]] = []
        self.placed: list[tuple[float, int]] = []
        self.gripper: int | None = None
        ids = itertools.count(1)
        order = [t for t, n in scenario.hopper.items() for _ in range(n)]
        self.rng.shuffle(order)
        self._outlines: dict[tuple[str, str], np.ndarray] = {}
        self._areas: dict[tuple[str, str], float] = {}
        self._radii: dict[tuple[str, str], float] = {}
        self._poses: dict[str, tuple[list[str], np.ndarray]] = {}
        for ptype in order:
            pid = next(ids)
            self.parts[pid] = SimPart(pid, str(ptype))
            self.hopper.append(pid)
        self.total = len(self.parts)
        self._ids = ids
        # supply (a supply plan, docs/supply.md): placed parts leave the cell instead of
        # going back to the hopper; the incline lifts ``lift`` times its nominal rate
        self.shipped: list[int] = []
        # wear: a part that has travelled the belt its type's max_passes times
        # goes to scrap when it falls off the end, not back to the hopper
        self.scrapped: list[int] = []
        self.ship_placed = False
        self.lift = 1.0
        self.next_release = self._draw_gap(0.0)

        # scheduled things
        self._timed: list[tuple[float, int, Callable[[float], None]]] = []
        self._seq = itertools.count()
        self.notifications: list[Notification] = []
        self.io: dict[str, bool] = {name: False for name in cell.io}

        # robot
        self.robot_pose = Pose(*cell.robot.safe_mm)
        self.speed_override_pct = 100.0     # the operator's override (a supply plan)
        self.robot_speed_pct = 100.0
        self.robot_busy: Job | None = None
        # the controller's own record (what a V+ program keeps): the commanded id of the
        # part it gripped, and of the last part it released at a place pose
        self.held_cmd: int | None = None
        self.last_placed_cmd: int | None = None

        # ground-truth statistics
        self.counts: Counter[str] = Counter()
        self.placed_by_type: Counter[str] = Counter()
        self.misplaced_by_type: Counter[str] = Counter()

        self._start_accounting()     # accounting by identity (accounting.py)
        # parts sliding on the belt (slip.py): each type's friction, none on an ideal cell
        self._start_slip(self.t, {k: (0.0, 0.0) if cell.sim.ideal else p.belt_friction(cell.sim)
                                  for k, p in scenario.parts.items()})

    # ------------------------------------------------------------------ time
    def schedule(self, t: float, fn: Callable[[float], None]) -> int:
        seq = next(self._seq)
        heapq.heappush(self._timed, (t, seq, fn))
        self.clock.wake_at(t)
        return seq

    def unschedule(self, seq: int) -> None:
        self._timed = [e for e in self._timed if e[1] != seq]
        heapq.heapify(self._timed)

    def now(self) -> float:
        """The clock's time, with every event up to it processed: commands issued between
        ticks (an operator's stop, a leaf's terminate) happen at the right instant."""
        t = self.clock.now()
        if t > self.t:
            self.step(t)
        return self.t

    def step(self, now: float) -> None:
        """Process every event up to ``now`` in time order."""
        limit = now + EPS
        while True:
            t, kind, arg = self._next_event()
            if t is None or t > limit:
                break
            self.t = max(self.t, t)
            self._slip_to(self.t)
            if arg is None:
                kind(self.t)
            else:
                kind(self.t, arg)
        self.t = now
        self._slip_to(now)
        if now >= self.passlog.next_t:
            self.passlog.sample(now, self.horizontal.pos(now))
        if self.notifications:
            self._hint_notifications()
        self.check_accounting()

    def _next_event(self) -> tuple[float | None, Callable[..., None], object]:
        """The earliest pending event: its time, handler and the handler's extra argument
        (None: none). Candidates are looked at in a fixed order and a later one wins only
        if strictly earlier. Runs every tick, so it is written out flat (no closures)."""
        best_t: float | None = None
        best_fn: Callable[..., None] = _noop
        best_arg: object = None
        now = self.t
        if self._timed:
            best_t, best_fn = self._timed[0][0], self._run_timed
        if self.hopper:
            t = self.incline.time_at(self.next_release, now)
            if t is not None and (best_t is None or t < best_t):
                best_t, best_fn = t, self._release
        if self.on_incline:
            front = self.parts[self.on_incline[0]]
            t = self.incline.time_at(front.p_release + self.i_len, now)
            if t is not None and (best_t is None or t < best_t):
                best_t, best_fn = t, self._land
        if self.on_horizontal:
            lead = max(self.on_horizontal.values(), key=_x0)
            t = self.horizontal.time_at(self.h_len - lead.x0, now)
            if t is not None and (best_t is None or t < best_t):
                best_t, best_fn, best_arg = t, self._fall, lead.id
        if self.returning:
            t = self.returning[0][0]
            if best_t is None or t < best_t:
                best_t, best_fn, best_arg = t, self._arrive_hopper, None
        if self.placed:
            t = self.placed[0][0]
            if best_t is None or t < best_t:
                best_t, best_fn, best_arg = t, self._recycle, None
        for n in self.notifications:
            t = n.axis.time_at(n.target, now)
            if t is not None and (best_t is None or t < best_t):
                best_t, best_fn, best_arg = t, self._notify, n
        return best_t, best_fn, best_arg

    def _run_timed(self, t: float) -> None:
        _, _, fn = heapq.heappop(self._timed)
        fn(t)

    # ------------------------------------------------------------------ part flow
    def _draw_gap(self, at: float) -> float:
        fill = min(1.0, len(self.hopper) / max(1, self.cell.hopper.nominal_fill))
        rate = self.cell.hopper.release_per_mm * max(fill, 1e-6) * self.lift
        return at + float(self.rng.exponential(1.0 / rate)) if rate > 0 else math.inf

    def _release(self, t: float) -> None:
        pid = self.hopper.popleft()
        part = self.parts[pid]
        self._relocate(part, "hopper", "incline")
        part.p_release = self.next_release
        spec = self.scenario.parts[part.type]
        names, cdf = self._pose_table(part.type)
        # what rng.choice(len(names), p=...) does, draw for draw, without its checks
        part.pose = names[int(cdf.searchsorted(self.rng.random(), side="right"))]
        part.pickable = spec.poses[part.pose].pickable
        part.angle = float(self.rng.uniform(-180.0, 180.0))
        part.y = float(self.rng.uniform(EDGE_MARGIN_MM, self.h_width - EDGE_MARGIN_MM))
        part.x0 = float(self.rng.uniform(*LAND_X_MM))      # landing x, fixed at release
        self.on_incline.append(pid)
        self.counts["released"] += 1
        self.next_release = self._draw_gap(self.next_release) if self.hopper else math.inf

    def _pose_table(self, ptype: str) -> tuple[list[str], np.ndarray]:
        """A part type's poses and the cumulative distribution ``rng.choice`` would build
        from their probabilities (the same arithmetic), made once."""
        table = self._poses.get(ptype)
        if table is None:
            spec = self.scenario.parts[ptype]
            names = list(spec.poses)
            probs = np.array([spec.poses[n].probability for n in names])
            p = probs / probs.sum()
            if not (np.all(p >= 0) and np.isfinite(p).all()):
                raise ValueError(f"part {ptype}: pose probabilities must be >= 0")
            cdf = p.cumsum()
            cdf /= cdf[-1]
            table = self._poses[ptype] = (names, cdf)
        return table

    def _land(self, t: float) -> None:
        pid = self.on_incline.popleft()
        part = self.parts[pid]
        part.outline = self.outline(part.type, part.pose)
        part.radius = self.radius(part.type, part.pose)
        land_x = part.x0
        part.x0 = land_x - self.horizontal.pos(t)
        self._relocate(part, "incline", "horizontal")
        self._imperfect_landing(part, t, dropped=False)
        self._settle(part, t)
        self.on_horizontal[pid] = part
        self.passlog.landed(pid, t, part.x0, part.y, part.type,
                            part.pickable and not part.touching)
        self.counts["landed"] += 1
        if part.touching:
            self.counts["landed_touching"] += 1

    def _fall(self, t: float, pid: int) -> None:
        if self.on_horizontal[pid].x0 + self.horizontal.pos(t) < self.h_len - 1e-6:
            return      # it slid back since its fall was foreseen (slip.py): not yet
        part = self.on_horizontal.pop(pid)
        self._untouch(part)
        part.passes += 1
        limit = self.scenario.parts[part.type].max_passes
        if limit and part.passes >= limit:      # worn out: to scrap, counted, never lost
            self._relocate(part, "horizontal", "scrapped")
            self.scrapped.append(pid)
            self.counts["scrapped"] += 1
            return
        self._relocate(part, "horizontal", "return")
        heapq.heappush(self.returning, (t + self.cell.return_transit_s, pid))
        self.counts["recirculated"] += 1

    def _arrive_hopper(self, t: float) -> None:
        _, pid = heapq.heappop(self.returning)
        self._to_hopper(pid, "return")

    def _recycle(self, t: float) -> None:
        _, pid = heapq.heappop(self.placed)
        if self.ship_placed:                    # it leaves the cell (a supply plan)
            self._relocate(self.parts[pid], "placed", "shipped")
            self.shipped.append(pid)
            self.counts["shipped"] += 1
        else:
            self._to_hopper(pid, "placed")

    def add_parts(self, types: list[str]) -> list[int]:
        """New parts arrive in the hopper (a tote): new identities, counted as supplied.
        The next release is drawn again at the new fill (the draws are memoryless)."""
        new = []
        for ptype in types:
            pid = next(self._ids)
            self.parts[pid] = SimPart(pid, ptype, where="hopper")
            self.hopper.append(pid)
            self.tally["hopper"] += 1
            new.append(pid)
        self.total += len(new)
        self.counts["supplied"] += len(new)
        if new:
            self.redraw_release()
        return new

    def redraw_release(self) -> None:
        """Draw the next release again from now: the fill or the lift changed."""
        self.next_release = (self._draw_gap(self.incline.pos(self.t)) if self.hopper
                             else math.inf)

    def _to_hopper(self, pid: int, src: str) -> None:
        was_empty = not self.hopper
        self._relocate(self.parts[pid], src, "hopper")
        self.parts[pid].touching.clear()
        self.hopper.append(pid)
        if was_empty:
            self.next_release = self._draw_gap(self.incline.pos(self.t))

    # ------------------------------------------------------------------ sensing
    def galil_count(self, t: float | None = None) -> int:
        t = self.now() if t is None else t
        return wrap(self.imperfect.galil_counts(self.horizontal.pos(t), t),
                    self.cell.encoder.conveyor_bits)

    def robot_count(self, t: float | None = None) -> int:
        """What the robot controller's belt channel reads at ``t``: the last sample, held
        for a sampling period (``sim.robot_sample_s``)."""
        t = self.now() if t is None else t
        enc = self.cell.encoder
        ts = self.imperfect.robot_sample_time(t)
        counts = self.imperfect.robot_counts(self.horizontal.pos(ts), ts)
        return wrap(enc.robot_start + self.robot_slip + counts, enc.robot_bits)

    def robot_track_count(self, t: float) -> int:
        """The belt count the arm's tracking follows at ``t``: the held sample carried
        forward by the belt speed averaged over the last ``TRACK_VAVG`` samples (V+'s
        DEFBELT velocity averaging, ``vavg`` in vplus/a_server.v2), so between samples the
        arm follows the belt, and after a speed change it lags until the average catches up."""
        T = self.imperfect.spec.robot_sample_s
        if self.imperfect.ideal or T <= 0:
            return self.robot_count(t)
        ts = self.imperfect.robot_sample_time(t)
        t_old = ts - TRACK_VAVG * T
        c_now = self.imperfect.robot_counts(self.horizontal.pos(ts), ts)
        c_old = self.imperfect.robot_counts(self.horizontal.pos(max(t_old, 0.0)), t_old)
        carried = c_now + round((c_now - c_old) / (TRACK_VAVG * T) * (t - ts))
        enc = self.cell.encoder
        return wrap(enc.robot_start + self.robot_slip + carried, enc.robot_bits)

    def visible_outlines(self, t: float, x_range: tuple[float, float]) -> list[np.ndarray]:
        """Outlines (belt frame, mm) of parts near the camera window at ``t``, for rendering."""
        lo, hi = x_range
        out = []
        for part in self.on_horizontal.values():
            x, y = self.part_xy(part, t)
            if lo - part.radius <= x <= hi + part.radius:
                out.append(place_outline(part.outline, x, y, part.angle))
        return out

    def truth(self, t: float | None = None) -> list[dict]:
        """Ground truth of parts on the horizontal belt, for tests and tools — never the locator."""
        t = self.t if t is None else t
        rows = []
        for p in self.on_horizontal.values():
            x, y = self.part_xy(p, t)
            rows.append({"id": p.id, "type": p.type, "pose": p.pose, "x_mm": x, "y_mm": y,
                         "angle_deg": p.angle, "pickable": p.pickable,
                         "singulated": p.singulated})
        return rows

    # ------------------------------------------------------------------ notifications
    def notify_travel(self, axis: Axis, distance: float, job: Job) -> None:
        n = Notification(axis, axis.pos(self.t) + distance, job)
        self.notifications.append(n)
        job.add_done_callback(lambda j, n=n: self._drop_notification(n))
        self._hint(n)

    def _drop_notification(self, n: Notification) -> None:
        if n in self.notifications:
            self.notifications.remove(n)

    def _notify(self, t: float, n: Notification) -> None:
        self._drop_notification(n)
        n.job.succeed(t)

    def _hint(self, n: Notification) -> None:
        when = n.axis.time_at(n.target, self.t)
        if when is not None:
            self.clock.wake_at(when)
        n.hinted_version = n.axis.version

    def _hint_notifications(self) -> None:
        for n in self.notifications:
            if n.hinted_version != n.axis.version:
                self._hint(n)


def _noop(t: float) -> None:
    pass


def _x0(part: SimPart) -> float:
    return part.x0
