"""Part location: latched grabs every ``frame_spacing_mm`` of belt, recipe, enqueue."""

from __future__ import annotations

import itertools
import math

from py_trees.common import Status

from feeder_bt.behaviours.base import Ctx, JobLeaf, Leaf
from feeder_bt.behaviours.keys import LOCATE, PRESENT
from feeder_bt.core.encoder import diff
from feeder_bt.core.jobs import Job
from feeder_bt.core.parts import Part
from feeder_bt.hal.interfaces import Frame
from feeder_bt.policy.supply_bound import ReachWindow
from feeder_bt.vision.latest import hand_over
from feeder_bt.vision.watch import recipe_watch


class WaitTravel(JobLeaf):
    """Continuous mode: the conveyor's distance notification paces the frames."""

    fault_key = LOCATE.ERROR        # so the fallbacks never act on a stale grab error
    WRITES = (LOCATE.ERROR,)
    recovers = ("comms_lost",)

    def start(self) -> Job:
        return self.ctx.hal.conveyors["horizontal"].travelled(
            self.ctx.scenario.locate.frame_spacing_mm)


class Grab(JobLeaf):
    """Trigger the camera; the same trigger latches the conveyor encoder."""

    fault_key = LOCATE.ERROR
    WRITES = (LOCATE.FRAME, LOCATE.ERROR)

    def start(self) -> Job:
        return self.ctx.hal.camera.grab()

    def on_success(self, result: Frame) -> Status:
        self.bb.set(LOCATE.FRAME, result)
        return Status.SUCCESS


class Recognise(JobLeaf):
    """Run the scenario's recipe on the frame, on the vision worker."""

    fault_key = LOCATE.ERROR
    READS = (LOCATE.FRAME,)
    WRITES = (LOCATE.RESULT, LOCATE.ERROR)

    def start(self) -> Job:
        return self.ctx.vision.recognise(self.bb.get(LOCATE.FRAME).image)

    def on_success(self, result) -> Status:
        self.bb.set(LOCATE.RESULT, result)
        self.ctx.stats.vision_ms.append(result.ms)
        self.ctx.stats.count("frames")
        return Status.SUCCESS


class SeenParts:
    """Parts located recently, to drop the same part seen again in an overlapping frame.

    Positions are compared at the new frame's latch: the old part's x moves by the belt
    travel between the two latches, read from the encoder."""

    def __init__(self, counts_per_mm: float, robot_bits: int, forget_beyond_mm: float) -> None:
        self.cpm, self.bits, self.forget = counts_per_mm, robot_bits, forget_beyond_mm
        self.parts: list[Part] = []

    def shift_mm(self, part: Part, latch: int) -> float:
        return diff(latch, part.latch, self.bits) / self.cpm

    def is_new(self, cand: Part, tol_mm: float) -> bool:
        for old in self.parts:
            if old.type != cand.type:
                continue
            x = old.x_mm + self.shift_mm(old, cand.latch)
            if math.hypot(x - cand.x_mm, old.y_mm - cand.y_mm) <= tol_mm:
                return False
        return True

    def add(self, part: Part) -> None:
        self.parts.append(part)

    def prune(self, latch: int) -> None:
        self.parts = [p for p in self.parts
                      if p.x_mm + self.shift_mm(p, latch) <= self.forget]


class Enqueue(Leaf):
    """Turn detections into parts in the belt frame, drop duplicates, queue the pickable."""

    _ids = itertools.count(1)
    READS = (LOCATE.FRAME, LOCATE.RESULT)
    WRITES = (LOCATE.FOUND,)

    def __init__(self, name: str, ctx: Ctx) -> None:
        super().__init__(name, ctx)
        cam = ctx.cell.camera
        window_end = cam.calibration.origin_mm[0] + cam.height_px * cam.calibration.mm_per_px
        seen = ctx.extras.get("seen")
        if seen is None:
            seen = SeenParts(ctx.cell.encoder.counts_per_mm, ctx.cell.encoder.robot_bits,
                             window_end + 200.0)
            ctx.extras["seen"] = seen
        self.seen: SeenParts = seen
        self.reach = ReachWindow(ctx.cell, ctx.scenario)     # for the supply bound

    @staticmethod
    def downstream_first(parts: list) -> list:
        """Nearest the robot first: with a limit per look, those are the ones to take."""
        return sorted(parts, key=lambda d: -d.x_mm)

    def update(self) -> Status:
        frame: Frame = self.bb.get(LOCATE.FRAME)
        result = self.bb.get(LOCATE.RESULT)
        latch = self.ctx.encoder.to_robot(frame.latch)
        self.seen.prune(latch)
        stats, new = self.ctx.stats, 0
        tol = self.ctx.scenario.locate.dedupe_mm
        limit = self.ctx.scenario.locate.max_parts_per_look
        dets = self.downstream_first(result.parts) if limit else result.parts
        limit = limit or len(dets)
        for det in dets:
            part = Part(id=next(self._ids), type=det.part, x_mm=det.x_mm, y_mm=det.y_mm,
                        angle_deg=det.angle_deg, latch=latch, located_at=frame.t,
                        pose=det.pose or "", pickable=det.pickable, frame=frame.index,
                        features=dict(det.features),
                        grip_dx_mm=getattr(det, "grip_dx_mm", 0.0),     # a plug-in's may
                        grip_dy_mm=getattr(det, "grip_dy_mm", 0.0),     # have none
                        grip_deg=getattr(det, "grip_deg", 0.0))
            if not self.seen.is_new(part, tol):
                stats.count("duplicates")
                continue
            if part.pickable and new >= limit:
                continue          # not seen: the next look finds it again
            self.seen.add(part)
            if part.pickable:
                self.ctx.queue.put(part)
                stats.count("located")
                if self.reach.crosses(part.x_mm, part.y_mm, part.type):
                    stats.count("located_in_reach")
                    stats.in_reach_by_type[part.type] += 1
                new += 1
                stats.emit(frame.t, "located", id=part.id, type=part.type,
                           x_mm=round(part.x_mm, 1), y_mm=round(part.y_mm, 1))
            else:
                stats.count("located_unpickable")
        stats.count("rejected_blobs", len(result.rejected))
        # what a twin's fit reads (tuning/twin.py): the frame's finds and every rejected
        # blob with its reason, area and place, as a real cell's log has them
        xs = [d.x_mm for d in result.parts] + [d.x_mm for d in result.rejected]
        stats.emit(frame.t, "frame", n=frame.index, latch=int(frame.latch), new=new,
                   parts=len(result.parts), pickable=sum(d.pickable for d in result.parts),
                   x_mm=round(sum(xs) / len(xs), 1) if xs else None, rejected=[
                       [d.reason.split(";")[0].split(" (")[0],
                        round(d.features.get("area_mm2", 0.0)),
                        round(d.x_mm, 1), round(d.y_mm, 1)] for d in result.rejected])
        blocked = sum(getattr(d, "reason", "") == "gripper blocked" for d in result.rejected)
        if blocked:                       # not offered: a neighbour where the gripper goes
            stats.count("gripper_blocked", blocked)
        recipe_watch(self.ctx.extras).feed(frame.t, result, stats)   # no silent zero
        hand_over(self.ctx.extras, frame, result)      # a reference, for the camera view
        self.bb.set(LOCATE.FOUND, new)
        self.feedback_message = f"frame {frame.index}: {new} new"
        return Status.SUCCESS


class QueueEmpty(Leaf):
    """Incremental mode: look again only when every part found has been dealt with — placed,
    missed, out of reach or too far — and the gripper is empty. An empty queue alone is
    not enough: the part just taken from it is still on the belt until the grip, and an
    advance requested meanwhile would move it from under the robot (thesis 1.2.3.4: the
    original feeder ran find, advance, pick strictly in series)."""

    def update(self) -> Status:
        if len(self.ctx.queue) or self.ctx.hal.robot.holding():
            return Status.RUNNING
        c = self.ctx.stats.counts
        dealt = (self.ctx.stats.total_retrieved + c["missed"] + c["unreachable"]
                 + c["too_far"])
        return Status.SUCCESS if dealt >= c["located"] else Status.RUNNING


class AdvanceIfNothing(Leaf):
    """Incremental mode: if the last frame found nothing, ask the presenter to advance
    (small; big after ``big_after`` empty frames in a row) and wait until it has."""

    READS = (LOCATE.FOUND, PRESENT.COMPLETED)
    WRITES = (PRESENT.REQUEST,)

    def __init__(self, name: str, ctx: Ctx, big_after: int = 3) -> None:
        super().__init__(name, ctx)
        self.big_after = big_after
        self.empty_run = big_after        # first advance loads the belt
        self.waiting_for: int | None = None

    def initialise(self) -> None:
        self.waiting_for = None

    def update(self) -> Status:
        if self.waiting_for is None:
            if self.bb.get(LOCATE.FOUND) > 0:
                self.empty_run = 0
                return Status.SUCCESS
            self.empty_run += 1
            kind = "big" if self.empty_run >= self.big_after else "small"
            if kind == "big":
                self.empty_run = 0
            self.bb.set(PRESENT.REQUEST, kind)
            self.waiting_for = self.bb.get(PRESENT.COMPLETED) + 1
            self.feedback_message = f"{kind} advance"
        if self.bb.get(PRESENT.COMPLETED) >= self.waiting_for:
            return Status.SUCCESS
        return Status.RUNNING


class ClearForGolden(JobLeaf):
    """Recovery: empty the belt under the camera before a new golden image. Continuous:
    hold the incline (``/present/hold``) and let the horizontal belt carry off every part
    on it; incremental: move the horizontal belt its length."""

    WRITES = (PRESENT.HOLD,)

    def start(self) -> Job:
        if self.ctx.hal.plate is not None:          # a plate is emptied by a purge
            return self.ctx.hal.plate.purge(10)
        conv = self.ctx.hal.conveyors["horizontal"]
        length = self.ctx.cell.conveyors["horizontal"].length_mm
        if self.ctx.scenario.present.mode == "continuous":
            self.bb.set(PRESENT.HOLD, True)
            return conv.travelled(length)
        return conv.move(length, self.ctx.cell.conveyors["horizontal"].max_mm_s)

    def terminate(self, new_status: Status) -> None:
        super().terminate(new_status)
        self.bb.set(PRESENT.HOLD, False)


class GrabGolden(JobLeaf):
    """Set-up: grab the golden image (an empty, lit belt) for image subtraction."""

    fault_key = LOCATE.ERROR
    WRITES = (LOCATE.ERROR,)

    def start(self) -> Job:
        return self.ctx.hal.camera.grab()

    def on_success(self, result: Frame) -> Status:
        self.ctx.vision.set_golden(result.image)
        self.ctx.stats.emit(self.ctx.now(), "golden_image", frame=result.index)
        return Status.SUCCESS
