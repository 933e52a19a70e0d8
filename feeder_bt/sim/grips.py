"""The robot in the simulated world: where it aims, when a pick can grip, and each grip
and release judged against the truth.

A grip holds only if the nearest part is under the cup, pickable and singulated, and then
with a probability that falls with the cup's offset from its centre
(``Imperfections.grip_probability``); a release counts a part misplaced or misoriented
against its own type's place pose. The controller's own record (what a V+ program keeps:
the commanded id it gripped and last placed) is kept apart from the truth.

``RobotGrips`` is a part of ``World`` (``world.py``), kept here by concept.
"""

from __future__ import annotations

import heapq
import math
from collections import Counter

import cv2
import numpy as np

from feeder_bt.core.encoder import diff
from feeder_bt.core.errors import EnvelopeError, HalError, MissedGrab
from feeder_bt.core.geometry import near, outer, place_outline, rings, wrap_deg
from feeder_bt.core.jobs import Job
from feeder_bt.core.model import CellSpec, Scenario, belt_window
from feeder_bt.hal.interfaces import Held, PickResult, PickTarget, Pose
from feeder_bt.robot.gripper import footprint, grip_poses
from feeder_bt.robot.scara import ScaraModel
from feeder_bt.sim.accounting import SimPart
from feeder_bt.sim.axis import Axis
from feeder_bt.sim.imperfect import Imperfections
from feeder_bt.sim.passlog import PassLog

RECYCLE_S = 20.0                # placed parts go back to the hopper after this long
PLACE_TOL_MM = 10.0             # a part released farther than this from its own type's
                                # place pose is misplaced (another type's station, say)


class RobotGrips:
    """The robot's aim, grips, releases and drops (a part of ``World``)."""

    # what it uses of the world (``World.__init__`` makes them)
    scenario: Scenario
    cell: CellSpec
    cpm: float
    parts: dict[int, SimPart]
    on_horizontal: dict[int, SimPart]
    returning: list[tuple[float, int]]
    placed: list[tuple[float, int]]
    gripper: int | None
    horizontal: Axis
    h_len: float
    h_width: float
    imperfect: Imperfections
    robot_model: ScaraModel
    passlog: PassLog
    robot_pose: Pose
    robot_busy: Job | None
    speed_override_pct: float
    held_cmd: int | None
    last_placed_cmd: int | None
    counts: Counter[str]
    placed_by_type: Counter[str]
    misplaced_by_type: Counter[str]
    #: seconds the arm waited at the reach's edge for parts it then gripped (the truth
    #: beside the report's ``robot_time``), and the wait of the pick last planned
    pick_waited_s: float = 0.0
    planned_wait_s: float = 0.0

    def commanded_xy(self, target: PickTarget, t: float) -> tuple[float, float]:
        """Where the robot aims for ``target`` at ``t``: tracking follows the belt encoder."""
        ox, oy, _ = target.tool_offset
        x = target.x_mm + ox
        if target.tracking:
            moved = diff(self.robot_track_count(t), target.latch,
                         self.cell.encoder.robot_bits)
            x += moved / self.cpm
        return x, target.y_mm + oy

    def plan_pick(self, target: PickTarget, t0: float, scale: float = 1.0
                  ) -> tuple[float, float]:
        """Intercept: the arrival time and grip time for a pick started at ``t0`` (the
        move taking ``scale`` times the nominal model's time)."""
        spec = self.cell.robot
        px, py = self.robot_pose.x, self.robot_pose.y
        self.planned_wait_s = 0.0     # at the reach's edge, for a part still upstream
        up, down, pick_limit = belt_window(self.cell)
        if target.tracking and self.commanded_xy(target, t0)[0] > pick_limit:
            raise EnvelopeError(f"part {target.part_id} is past the pick limit "
                                f"({pick_limit:.0f} mm): outside the belt window")
        t_arr = t0
        for _ in range(6):
            cx, cy = self.commanded_xy(target, t_arr)
            t_arr = t0 + scale * self.robot_model.move_time((px, py), (cx, cy),
                                                            self.robot_speed_pct)
        cx, cy = self.commanded_xy(target, t_arr)
        upstream = target.tracking and cx < up       # V+ waits for it to enter the window
        if upstream or not self.robot_model.reachable(cx, cy):
            t_enter = self._time_entering_reach(target, cy, t0)
            if t_enter is None or t_enter < t_arr:
                raise EnvelopeError(f"part {target.part_id} at x={cx:.0f} y={cy:.0f} mm "
                                    "is out of reach")
            self.planned_wait_s = t_enter - t_arr
            t_arr = t_enter
        t_grip = t_arr + (spec.track_settle_s if target.tracking else 0.0) + spec.grip_s
        gx, gy = self.commanded_xy(target, t_grip)
        if not self.robot_model.reachable(gx, gy):
            raise EnvelopeError(f"part {target.part_id} leaves the reach before the grip")
        if target.tracking and gx > down:
            raise EnvelopeError(f"part {target.part_id} leaves the belt window ({down:.0f} "
                                "mm) before the grip")
        return t_arr, t_grip

    def _time_entering_reach(self, target: PickTarget, cy: float, t0: float) -> float | None:
        spec = self.cell.robot
        bx, by = spec.base_mm
        if abs(cy - by) >= spec.reach_mm:
            return None
        x_enter = max(bx - math.sqrt(spec.reach_mm ** 2 - (cy - by) ** 2),
                      belt_window(self.cell)[0]) + 1.0
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
            d = self._grip_distance(part, cx, cy, t)
            if d < best_d:
                best, best_d = part, d
        if best is None or best_d > self.imperfect.grip_reach_mm():
            self.counts["grip_empty"] += 1
            raise MissedGrab(f"nothing under the gripper at x={cx:.1f} y={cy:.1f} mm")
        if not best.pickable or not best.singulated:
            self.counts["grip_refused"] += 1
            why = "not singulated" if best.pickable else f"lying {best.pose}"
            raise MissedGrab(f"part under the gripper is {why}")
        self._judge_footprint(best, cx, cy, target.angle_deg + target.grip_deg, t)
        if not self.imperfect.grip_holds(best_d):
            self.counts["grip_slipped"] += 1
            raise MissedGrab(f"the grip did not hold ({best_d:.1f} mm off the centre)")
        self.on_horizontal.pop(best.id)
        self.passlog.picked(best.id, t, cx, cy, best.type)
        self._untouch(best)
        self._relocate(best, "horizontal", "gripper")
        best.held_error_deg = wrap_deg(best.angle - target.angle_deg)
        self.gripper = best.id
        self.held_cmd = target.part_id
        self.counts["gripped"] += 1
        return PickResult(part_id=best.id, t=t, belt_x_mm=cx)

    def _grip_distance(self, part: SimPart, cx: float, cy: float, t: float) -> float:
        """How far the gripper at (cx, cy) is from where the part is meant to be gripped
        (its nearest grip, ``PartSpec.pick``; else its centroid)."""
        x, y = self.part_xy(part, t)
        spec = self.scenario.parts[part.type]
        d = math.hypot(x - cx, y - cy)
        if spec.pick is None or d > part.radius + self.imperfect.grip_reach_mm():
            return d
        # a symmetric part is the same part turned by its period: so are its grips
        mirrored = spec.poses[part.pose].mirror
        grips = [g for k in range(spec.symmetry)
                 for g in grip_poses(spec.pick, x, y, part.angle + k * spec.period_deg,
                                     mirrored)]
        return min(math.hypot(gx - cx, gy - cy) for gx, gy, _ in grips)

    def _judge_footprint(self, part: SimPart, cx: float, cy: float, angle: float,
                         t: float) -> None:
        """A cup over a hole of the part grips nothing; a gripper whose footprint lands on
        a neighbour does not reach the part. Judged on the true outlines."""
        x, y = self.part_xy(part, t)
        placed = place_outline(part.outline, x, y, part.angle)
        for hole in rings(placed)[1:]:
            if cv2.pointPolygonTest(hole.astype(np.float32).reshape(-1, 1, 2),
                                    (float(cx), float(cy)), False) > 0:
                self.counts["grip_on_hole"] += 1
                raise MissedGrab(f"the gripper is over a hole of part {part.id}")
        pick = self.scenario.parts[part.type].pick
        if pick is None:
            return
        foot = footprint(pick, cx, cy, angle)
        if not foot:
            return
        reach = max(float(np.hypot(*(r - (cx, cy)).T).max()) for r in foot)
        for other in self.on_horizontal.values():
            if other is part:
                continue
            ox, oy = self.part_xy(other, t)
            if math.hypot(ox - cx, oy - cy) > reach + other.radius:
                continue
            ring = outer(place_outline(other.outline, ox, oy, other.angle))
            if any(near(f, ring, 0.0) for f in foot):
                self.counts["grip_on_neighbour"] += 1
                raise MissedGrab(f"the gripper lands on part {other.id} beside part {part.id}")

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
        # how far the placed part is from angle 0, modulo the turns it looks the same after
        # (its ``symmetry``): the place pose turned it by -angle as located, which the held
        # error is the truth's difference from
        if spec.place.orient and abs(wrap_deg(part.held_error_deg, spec.period_deg)) > \
                spec.orientation_tolerance_deg:
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
            self.passlog.landed(pid, t, part.x0, part.y, part.type,
                                part.pickable and not part.touching)
        else:
            self._relocate(part, "gripper", "return")
            heapq.heappush(self.returning, (t + self.cell.return_transit_s, pid))
        self.counts["dropped"] += 1
