"""The simulated feeder: hopper, inclined and horizontal conveyors, return conveyor, robot.

A discrete-event world on virtual time. Belt motion is analytic (``Axis``), so every event
— a part leaving the hopper, landing on the horizontal belt, falling off its end, a grip —
happens at an exact virtual time that does not depend on how often the world is stepped.

Honesty: the world knows where every part truly is; it hands the camera outlines to
render into pixels and judges each grip against the truth. Nothing here is shown to the
locator.

Accounting by identity: every part is always in exactly one place. Each part carries its
own record (``SimPart.where``); every move between places checks that record against the
place it leaves and keeps a tally of the records by place. Every step compares the tally
with the containers' sizes (seven integers), and a full audit matches each part's record
against the containers one by one whenever they disagree, every ``AUDIT_EVERY`` steps and
at every census. A part found nowhere is *lost*, one found in two places *duplicated*:
each is named with its id and last known place (``problems``), counted, and told to the
``listeners`` — the run then ends with its own exit code (docs/faults.md).
"""

from __future__ import annotations

import heapq
import itertools
import math
from collections import Counter, deque
from collections.abc import Callable
from dataclasses import dataclass, field

import cv2
import numpy as np

from ...clock import EPS, SimClock
from ...encoder import diff, wrap
from ...errors import EnvelopeError, HalError, MissedGrab
from ...geometry import (
    circumradius,
    is_convex,
    near,
    outer,
    place_outline,
    pose_outline,
    wrap_deg,
)
from ...jobs import Job
from ...robot_model import RobotModel
from ...scenario.model import CellSpec, Scenario
from ..interfaces import Held, PickResult, PickTarget, Pose
from .axis import Axis
from .imperfect import Imperfections

PLACES = ("hopper", "incline", "horizontal", "return", "gripper", "placed", "shipped")
LAND_X_MM = (15.0, 45.0)        # where parts land on the horizontal belt, off the ramp
EDGE_MARGIN_MM = 28.0           # side rails keep parts this far from the belt edges
TOUCH_GAP_MM = 1.0              # closer than this, two parts count as touching
RECYCLE_S = 20.0                # placed parts go back to the hopper after this long
PLACE_TOL_MM = 10.0             # a part released farther than this from its own type's
                                # place pose is misplaced (another type's station, say)
AUDIT_EVERY = 32                # steps between full audits when the tallies agree


@dataclass
class SimPart:
    id: int
    type: str
    pose: str = ""
    pickable: bool = False
    where: str = "hopper"
    outline: np.ndarray | None = None
    radius: float = 0.0
    p_release: float = 0.0      # incline position at release
    x0: float = 0.0             # belt-frame x minus horizontal belt position at landing
    y: float = 0.0
    angle: float = 0.0
    touching: set[int] = field(default_factory=set)
    held_error_deg: float = 0.0
    # settling after a landing (imperfect.py): the rest pose is (x0, y); until settle_end
    # the part is still sliding towards it, short of it by slide * (1 - s)^2
    slide: tuple[float, float] = (0.0, 0.0)
    settle_t0: float = 0.0
    settle_end: float = -math.inf

    @property
    def singulated(self) -> bool:
        return not self.touching


@dataclass
class Notification:
    axis: Axis
    target: float
    job: Job
    hinted_version: int = -1


class World:
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
        self.robot_model = RobotModel(cell.robot)
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

        # accounting by identity
        self.tally: Counter[str] = Counter({"hopper": self.total})
        self.problems: list[dict] = []          # every part lost or duplicated, named
        self.reported: set[tuple[str, int]] = set()
        self.listeners: list[Callable[[dict], None]] = []
        self._steps = 0
        self._audit_due = False

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
            if arg is None:
                kind(self.t)
            else:
                kind(self.t, arg)
        self.t = now
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
        part.radius = circumradius(part.outline)
        land_x = part.x0
        part.x0 = land_x - self.horizontal.pos(t)
        self._relocate(part, "incline", "horizontal")
        self._imperfect_landing(part, t, dropped=False)
        self._settle(part, t)
        self.on_horizontal[pid] = part
        self.counts["landed"] += 1
        if part.touching:
            self.counts["landed_touching"] += 1

    def _settle(self, part: SimPart, t: float) -> None:
        """A part comes to rest on the horizontal belt (landing, or dropped by the robot):
        which parts does it touch?"""
        belt = self.horizontal.pos(t)
        ax, ay = part.x0 + belt, part.y             # part_xy(part, t)
        for other in self.on_horizontal.values():
            # _touch's own first test, here without a call per part on the belt
            if other is part or math.hypot(ax - (other.x0 + belt), ay - other.y) > \
                    part.radius + other.radius + TOUCH_GAP_MM:
                continue
            if self._touch(part, other, t):
                part.touching.add(other.id)
                other.touching.add(part.id)

    def _fall(self, t: float, pid: int) -> None:
        part = self.on_horizontal.pop(pid)
        self._untouch(part)
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

    def outline(self, ptype: str, pose: str) -> np.ndarray:
        """A part's outline in a pose (part frame; with holes, NaN rows part its rings: see
        ``feeder_bt.geometry``), made once per part type and pose."""
        key = (ptype, pose)
        if key not in self._outlines:
            self._outlines[key] = pose_outline(self.scenario.parts[ptype], pose)
        return self._outlines[key]

    def part_xy(self, part: SimPart, t: float) -> tuple[float, float]:
        if t < part.settle_end:                 # still sliding to its rest pose
            left = (1.0 - (t - part.settle_t0) / (part.settle_end - part.settle_t0)) ** 2
            return (part.x0 + self.horizontal.pos(t) - part.slide[0] * left,
                    part.y - part.slide[1] * left)
        return part.x0 + self.horizontal.pos(t), part.y

    def _imperfect_landing(self, part: SimPart, t: float, dropped: bool) -> None:
        """A landing part may come down against or on the one before it (parts leave the
        hopper in clumps), then slides and turns a little while it settles; its touching
        is judged at its rest pose. Nothing happens on an ideal cell."""
        imp = self.imperfect
        if imp.ideal:
            return
        prev = self.on_horizontal.get(self._last_landed) if not dropped else None
        if not dropped:
            self._last_landed = part.id
        if prev is not None and (c := imp.clump()) is not None:
            ang, frac = c
            dist = frac * (part.radius + prev.radius)
            part.x0 = prev.x0 + dist * math.cos(ang)
            part.y = prev.y + dist * math.sin(ang)
            self.counts["landed_clumped"] += 1
        dx, dy, turn, settle = imp.landing(dropped)
        y_rest = min(max(part.y + dy, EDGE_MARGIN_MM), self.h_width - EDGE_MARGIN_MM)
        part.slide = (dx, y_rest - part.y)
        part.x0 += dx
        part.y = y_rest
        part.angle = wrap_deg(part.angle + turn)
        part.settle_t0, part.settle_end = t, (t + settle if settle > 0 else -math.inf)

    def _touch(self, a: SimPart, b: SimPart, t: float) -> bool:
        """Whether two parts on the belt are closer than ``TOUCH_GAP_MM``. Convex outlines:
        their grown polygons intersect (exact, fast). Otherwise (concave outlines; holes do
        not matter, only the outer rings can meet): ``geometry.near`` on a fine raster."""
        ax, ay = self.part_xy(a, t)
        bx, by = self.part_xy(b, t)
        if math.hypot(ax - bx, ay - by) > a.radius + b.radius + TOUCH_GAP_MM:
            return False
        oa, ob = outer(a.outline), outer(b.outline)
        if is_convex(oa) and is_convex(ob):
            pa = _grown(place_outline(oa, ax, ay, a.angle), (ax, ay), TOUCH_GAP_MM / 2)
            pb = _grown(place_outline(ob, bx, by, b.angle), (bx, by), TOUCH_GAP_MM / 2)
            area, _ = cv2.intersectConvexConvex(pa.astype(np.float32), pb.astype(np.float32))
            return area > 0.0
        return near(place_outline(oa, ax, ay, a.angle), place_outline(ob, bx, by, b.angle),
                    TOUCH_GAP_MM)

    def _untouch(self, part: SimPart) -> None:
        for oid in part.touching:
            self.parts[oid].touching.discard(part.id)
        part.touching.clear()

    # ------------------------------------------------------------------ sensing
    def galil_count(self, t: float | None = None) -> int:
        t = self.now() if t is None else t
        return wrap(self.imperfect.galil_counts(self.horizontal.pos(t), t),
                    self.cell.encoder.conveyor_bits)

    def robot_count(self, t: float | None = None) -> int:
        t = self.now() if t is None else t
        enc = self.cell.encoder
        ts = self.imperfect.robot_sample_time(t)
        counts = self.imperfect.robot_counts(self.horizontal.pos(ts), ts)
        return wrap(enc.robot_start + self.robot_slip + counts, enc.robot_bits)

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

    # ------------------------------------------------------------------ robot
    def commanded_xy(self, target: PickTarget, t: float) -> tuple[float, float]:
        """Where the robot aims for ``target`` at ``t``: tracking follows the belt encoder."""
        ox, oy, _ = target.tool_offset
        x = target.x_mm + ox
        if target.tracking:
            moved = diff(self.robot_count(t), target.latch, self.cell.encoder.robot_bits)
            x += moved / self.cpm
        return x, target.y_mm + oy

    def plan_pick(self, target: PickTarget, t0: float, scale: float = 1.0
                  ) -> tuple[float, float]:
        """Intercept: the arrival time and grip time for a pick started at ``t0`` (the
        move taking ``scale`` times the nominal model's time)."""
        spec = self.cell.robot
        px, py = self.robot_pose.x, self.robot_pose.y
        t_arr = t0
        for _ in range(6):
            cx, cy = self.commanded_xy(target, t_arr)
            t_arr = t0 + scale * self.robot_model.arch_time(math.hypot(cx - px, cy - py),
                                                            self.robot_speed_pct)
        cx, cy = self.commanded_xy(target, t_arr)
        if not self.robot_model.reachable(cx, cy):
            t_enter = self._time_entering_reach(target, cy, t0)
            if t_enter is None or t_enter < t_arr:
                raise EnvelopeError(f"part {target.part_id} at x={cx:.0f} y={cy:.0f} mm "
                                    "is out of reach")
            t_arr = t_enter
        t_grip = t_arr + (spec.track_settle_s if target.tracking else 0.0) + spec.grip_s
        gx, gy = self.commanded_xy(target, t_grip)
        if not self.robot_model.reachable(gx, gy):
            raise EnvelopeError(f"part {target.part_id} leaves the reach before the grip")
        return t_arr, t_grip

    def _time_entering_reach(self, target: PickTarget, cy: float, t0: float) -> float | None:
        spec = self.cell.robot
        bx, by = spec.base_mm
        if abs(cy - by) >= spec.reach_mm:
            return None
        x_enter = bx - math.sqrt(spec.reach_mm ** 2 - (cy - by) ** 2) + 1.0
        cx, _ = self.commanded_xy(target, t0)
        if cx >= x_enter or not target.tracking:
            return None
        return self.horizontal.time_at(self.horizontal.pos(t0) + (x_enter - cx), t0)

    def grip(self, target: PickTarget, t: float) -> PickResult:
        """Judge a grip against the truth: the nearest part must be under the cup,
        pickable and singulated, and the grip holds with a probability that falls with
        the cup's offset from its centre (``Imperfections.grip_probability``)."""
        cx, cy = self.commanded_xy(target, t)
        self.robot_pose = Pose(cx, cy, 0.0, target.angle_deg)
        if self.gripper is not None:      # one suction cup: the held part stays held
            self.counts["grip_while_holding"] += 1
            raise HalError(f"the gripper already holds part {self.gripper}")
        best, best_d = None, math.inf
        for part in self.on_horizontal.values():
            x, y = self.part_xy(part, t)
            d = math.hypot(x - cx, y - cy)
            if d < best_d:
                best, best_d = part, d
        if best is None or best_d > self.imperfect.grip_reach_mm():
            self.counts["grip_empty"] += 1
            raise MissedGrab(f"nothing under the gripper at x={cx:.1f} y={cy:.1f} mm")
        if not best.pickable or not best.singulated:
            self.counts["grip_refused"] += 1
            why = "not singulated" if best.pickable else f"lying {best.pose}"
            raise MissedGrab(f"part under the gripper is {why}")
        if not self.imperfect.grip_holds(best_d):
            self.counts["grip_slipped"] += 1
            raise MissedGrab(f"the grip did not hold ({best_d:.1f} mm off the centre)")
        self.on_horizontal.pop(best.id)
        self._untouch(best)
        self._relocate(best, "horizontal", "gripper")
        best.held_error_deg = wrap_deg(best.angle - target.angle_deg)
        self.gripper = best.id
        self.held_cmd = target.part_id
        self.counts["gripped"] += 1
        return PickResult(part_id=best.id, t=t, belt_x_mm=cx)

    def release(self, pose: Pose, t: float) -> int | None:
        """Put the held part down at ``pose``; judge its orientation against the truth."""
        self.robot_pose = pose
        pid, self.gripper = self.gripper, None
        if pid is None:
            return None
        part = self.parts[pid]
        self._relocate(part, "gripper", "placed")
        heapq.heappush(self.placed, (t + RECYCLE_S, pid))
        self.last_placed_cmd, self.held_cmd = self.held_cmd, None
        self.placed_by_type[part.type] += 1
        spec = self.scenario.parts[part.type]
        if math.hypot(pose.x - spec.place.x, pose.y - spec.place.y) > PLACE_TOL_MM:
            self.misplaced_by_type[part.type] += 1     # another type's station, say
        if spec.place.orient and abs(part.held_error_deg) > spec.orientation_tolerance_deg:
            self.counts["misoriented"] += 1
        return pid

    @property
    def robot_speed_pct(self) -> float:
        """The speed the robot moves at: the commanded % times the operator's override."""
        return self._speed_cmd_pct * (self.speed_override_pct / 100.0)   # exact at 100 %

    @robot_speed_pct.setter
    def robot_speed_pct(self, pct: float) -> None:
        self._speed_cmd_pct = pct

    def held_now(self) -> Held:
        """The controller's word on its gripper (``Robot.held``): the commanded id it
        recorded at the grip, ``unknown`` for a part no pick of ours gripped."""
        if self.gripper is None:
            return Held(None, False, self.last_placed_cmd)
        return Held(self.held_cmd, self.held_cmd is None, self.last_placed_cmd)

    def drop_held(self, t: float) -> None:
        """A held part falls back onto the belt (or the return chute) where the robot is."""
        if self.gripper is None:
            return
        pid, self.gripper = self.gripper, None
        self.held_cmd = None
        part = self.parts[pid]
        x, y = self.robot_pose.x, self.robot_pose.y
        if 0.0 <= x < self.h_len and 0.0 <= y <= self.h_width:
            self._relocate(part, "gripper", "horizontal")
            part.x0, part.y = x - self.horizontal.pos(t), y
            self._imperfect_landing(part, t, dropped=True)
            self._settle(part, t)               # it may land on or against another
            self.on_horizontal[pid] = part
        else:
            self._relocate(part, "gripper", "return")
            heapq.heappush(self.returning, (t + self.cell.return_transit_s, pid))
        self.counts["dropped"] += 1

    # ------------------------------------------------------------------ accounting
    def _relocate(self, part: SimPart, src: str, dst: str) -> None:
        """Move a part's own record from ``src`` to ``dst``. A record that does not say
        ``src`` means the containers and the records disagree: audit at once."""
        if part.where != src:
            self._report([{"kind": "misrecorded", "id": part.id, "type": part.type,
                           "last_place": part.where, "places": [src]}])
            self._audit_due = True
        self.tally[part.where] -= 1
        self.tally[dst] += 1
        part.where = dst

    def _sizes(self) -> dict[str, int]:
        return {
            "hopper": len(self.hopper),
            "incline": len(self.on_incline),
            "horizontal": len(self.on_horizontal),
            "return": len(self.returning),
            "gripper": 0 if self.gripper is None else 1,
            "placed": len(self.placed),
            "shipped": len(self.shipped),
        }

    def census(self) -> dict[str, int]:
        self.audit()
        return self._sizes()

    def check_accounting(self) -> None:
        """Every step: the records' tally against the containers' sizes (cheap); a full
        audit, part by part, when they disagree and every ``AUDIT_EVERY`` steps."""
        self._steps += 1
        t = self.tally
        if (self._audit_due or self._steps % AUDIT_EVERY == 0
                or len(self.hopper) != t["hopper"] or len(self.on_incline) != t["incline"]
                or len(self.on_horizontal) != t["horizontal"]
                or len(self.returning) != t["return"] or len(self.placed) != t["placed"]
                or len(self.shipped) != t["shipped"]
                or (self.gripper is not None) != t["gripper"]):
            self.audit()

    def _containers(self):
        yield "hopper", self.hopper
        yield "incline", self.on_incline
        yield "horizontal", self.on_horizontal.keys()
        yield "return", (pid for _, pid in self.returning)
        yield "gripper", () if self.gripper is None else (self.gripper,)
        yield "placed", (pid for _, pid in self.placed)
        yield "shipped", self.shipped

    def audit(self) -> list[dict]:
        """Match every part against the containers by identity; name each part that is
        in no place (lost) or in more than one (duplicated, or an id nobody made). Returns
        the problems found for the first time; the tallies are then taken from the
        containers so that one problem is reported once."""
        self._audit_due = False
        found: dict[int, list[str]] = {}
        for place, ids in self._containers():
            for pid in ids:
                found.setdefault(pid, []).append(place)
        new: list[dict] = []
        for pid, part in self.parts.items():
            places = found.get(pid)
            if not places:
                new.append({"kind": "lost", "id": pid, "type": part.type,
                            "last_place": part.where})
            elif len(places) > 1:
                new.append({"kind": "duplicated", "id": pid, "type": part.type,
                            "places": places})
            elif places[0] != part.where:       # one place, but its record says another
                new.append({"kind": "misrecorded", "id": pid, "type": part.type,
                            "last_place": part.where, "places": places})
                part.where = places[0]
        for pid in found.keys() - self.parts.keys():
            new.append({"kind": "duplicated", "id": pid, "type": None, "places": found[pid]})
        new = self._report(new)
        if new or self._tally_off():
            self.tally = Counter(self._sizes())
        return new

    def _report(self, problems: list[dict]) -> list[dict]:
        """Record and tell each problem not reported before; returns those."""
        new = [p for p in problems if (p["kind"], p["id"]) not in self.reported]
        for p in new:
            p["t"] = round(self.t, 3)
            self.reported.add((p["kind"], p["id"]))
            self.problems.append(p)
            for fn in self.listeners:
                fn(p)
        return new

    def _tally_off(self) -> bool:
        sizes = self._sizes()
        return any(self.tally[k] != v for k, v in sizes.items())

    def lost(self) -> int:
        return sum(1 for p in self.problems if p["kind"] == "lost")

    def duplicated(self) -> int:
        return sum(1 for p in self.problems if p["kind"] == "duplicated")

    @property
    def broken(self) -> bool:
        """A part was lost or duplicated: the world can no longer be trusted."""
        return bool(self.problems)


def _grown(poly: np.ndarray, centre: tuple[float, float], by: float) -> np.ndarray:
    c = np.asarray(centre)
    v = poly - c
    n = np.linalg.norm(v, axis=1, keepdims=True)
    return c + v * (1.0 + by / np.maximum(n, 1e-9))


def _noop(t: float) -> None:
    pass


def _x0(part: SimPart) -> float:
    return part.x0
