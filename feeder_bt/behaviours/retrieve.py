"""Part retrieval: choose the next part, check it is not too far, pick it (tracking the
belt), place it, count it.

The cell records what it told the robot to do with the part (``/retrieve/phase``: "pick",
"held", "place") before each command leaves, so that after a lost reply ``Reconcile`` can
ask the controller what the gripper holds (``Robot.held``) and settle where the part
really is: still on the belt, in the gripper, or placed."""

from __future__ import annotations

from py_trees.common import Status

from feeder_bt.behaviours.base import Ctx, JobLeaf, Leaf
from feeder_bt.behaviours.keys import RETRIEVE, SPEEDS
from feeder_bt.behaviours.policies import POLICIES, gone_by
from feeder_bt.core.errors import HalError, UnknownPart
from feeder_bt.core.geometry import wrap_deg
from feeder_bt.core.jobs import Job
from feeder_bt.core.parts import Part
from feeder_bt.hal.interfaces import Held, PickTarget, Pose
from feeder_bt.policy.kits import KitTracker
from feeder_bt.robot.fit import Timing, robot_fit


def belt_x_now(ctx: Ctx, part: Part) -> float:
    """Where ``part`` is along the belt now, by the robot's belt encoder."""
    enc = ctx.hal.robot_position.belt_encoder()
    return part.x_at(enc, ctx.cell.encoder.robot_bits, ctx.cell.encoder.counts_per_mm)


class NextPart(Leaf):
    """Take the next part by policy; drop parts already too far to catch (thesis 5.2.2
    ``too_far``). RUNNING while the queue is empty — it never blocks."""

    READS = (SPEEDS.HORIZONTAL, SPEEDS.ROBOT)
    WRITES = (RETRIEVE.PART, RETRIEVE.ERROR)

    def __init__(self, name: str, ctx: Ctx) -> None:
        super().__init__(name, ctx)
        self.policy = POLICIES[ctx.scenario.retrieve.policy](ctx)
        kit = KitTracker.of(ctx.scenario.retrieve)
        stats = ctx.stats
        if kit is None or stats.kit is None or stats.kit.counts != kit.counts \
                or stats.kit.order != kit.order or stats.kit.open_kits != kit.open_kits:
            stats.kit = kit                 # kept across a restart: the kit half built

    def x_now(self, part: Part) -> float:
        return belt_x_now(self.ctx, part)

    def update(self) -> Status:
        r = self.ctx.scenario.retrieve
        queue = self.ctx.queue
        if len(queue) == 0:
            self.feedback_message = "waiting for a part"
            return Status.RUNNING
        self.policy.belt_mm_s = float(self.bb.get(SPEEDS.HORIZONTAL))
        self.policy.robot_pct = float(self.bb.get(SPEEDS.ROBOT))
        lead = self.policy.belt_mm_s * self.policy.lead_s() if r.tracking else 0.0
        gone = queue.take(gone_by(self.ctx, self.x_now, lead))
        if gone:
            self.ctx.stats.count("too_far", len(gone))
        kit = self.ctx.stats.kit
        wanted = kit.wanted() if kit is not None else None
        parts = [p for p in queue.peek_all() if wanted is None or p.type in wanted]
        part = self.policy.choose(parts, self.x_now)
        if part is None or not queue.remove(part.id):
            self.feedback_message = (f"waiting for a {' or '.join(sorted(wanted))}"
                                     if wanted else "waiting for a part")
            return Status.RUNNING
        self.bb.set(RETRIEVE.PART, part)
        self.bb.set(RETRIEVE.ERROR, None)
        self.feedback_message = f"part {part.id} ({part.type})"
        return Status.SUCCESS


PHASE = RETRIEVE.PHASE


class FailedPicksBelow(Leaf):
    """One more pick of the part's type failed (missed, out of reach): SUCCESS while fewer
    than the scenario's ``max_failed_picks`` have failed since the last part of that type
    placed, FAILURE at the limit, so the branch calls the operator. A robot in the wrong
    frame, a gripper without vacuum, a grip over a part's hole fails every pick: counting
    each miss is not enough, the cell must stop. By type, since a part that cannot be
    gripped fails between picks of another that can."""

    READS = (RETRIEVE.PART,)

    def update(self) -> Status:
        stats, limit = self.ctx.stats, self.ctx.scenario.retrieve.max_failed_picks
        part = self.bb.get(RETRIEVE.PART)
        ptype = part.type if part is not None else "?"
        stats.failed_picks_in_a_row[ptype] += 1
        n = stats.failed_picks_in_a_row[ptype]
        self.feedback_message = f"{n} {ptype} picks failed in a row (limit {limit or 'none'})"
        return Status.FAILURE if limit and n >= limit else Status.SUCCESS


def count_retrieved(ctx: Ctx, part: Part, **data: object) -> None:
    """The part is at its place pose: count it, once."""
    stats = ctx.stats
    stats.retrieved[part.type] += 1
    stats.last_retrieved = part.type
    stats.failed_picks_in_a_row[part.type] = 0
    stats.count("retrieved")
    stats.emit(ctx.now(), "retrieved", id=part.id, type=part.type, **data)
    if stats.kit is not None and stats.kit.placed(part.type):
        stats.count("kits")
        stats.emit(ctx.now(), "kit", number=stats.kit.completed)


class PartJob(JobLeaf):
    """A robot job about the part the retriever chose (``/retrieve/part``).

    A pick or place is timed on the cell's clock (``timing``) for the robot model fitted
    online (``feeder_bt.robot.fit``); only one that ends by itself, successfully, counts."""

    fault_key = RETRIEVE.ERROR
    READS = (RETRIEVE.PART, SPEEDS.ROBOT)
    WRITES = (PHASE, RETRIEVE.ERROR)

    def __init__(self, name: str, ctx: Ctx) -> None:
        super().__init__(name, ctx)
        self.timing: Timing | None = None

    @property
    def part(self) -> Part:
        return self.bb.get(RETRIEVE.PART)

    def _timing(self, kind: str, **kw: object) -> Timing:
        pose = self.ctx.hal.robot_position.pose()
        pct = float(self.bb.get(SPEEDS.ROBOT))
        return Timing(kind, self.ctx.now(), (pose.x, pose.y), pct, **kw)  # type: ignore[arg-type]


class Pick(PartJob):
    def start(self) -> Job:
        part = self.part
        spec = self.ctx.scenario.parts[part.type]
        self.feedback_message = f"picking part {part.id}"
        self.bb.set(PHASE, "pick")          # recorded before the command leaves
        ox, oy, _ = spec.tool_offset
        ox, oy = ox + part.grip_dx_mm, oy + part.grip_dy_mm      # the grip offered
        x, y = belt_x_now(self.ctx, part) + ox, part.y_mm + oy
        tracking = self.ctx.scenario.retrieve.tracking
        self.timing = self._timing(      # in reach now: the arm cannot wait for the part
            "pick", usable=robot_fit(self.ctx).nominal.reachable(x, y), tool_y=y,
            belt_mm_s=self.ctx.hal.conveyors["horizontal"].speed(), tracking=tracking)
        robot_fit(self.ctx).pick_commanded(self.timing)
        return self.ctx.hal.robot.pick(PickTarget(
            part_id=part.id, x_mm=part.x_mm + part.grip_dx_mm,
            y_mm=part.y_mm + part.grip_dy_mm, angle_deg=part.angle_deg,
            latch=part.latch, tracking=self.ctx.scenario.retrieve.tracking,
            grip_deg=part.grip_deg,
            tool_offset=tuple(spec.tool_offset)))

    def on_success(self, result: object) -> Status:
        self.bb.set(PHASE, "held")
        grip_x = getattr(result, "belt_x_mm", None)
        if self.timing is not None and grip_x is not None:
            robot_fit(self.ctx).pick_done(self.timing, self.ctx.now(), float(grip_x))
        self._log("held", grip_x)
        self.timing = None
        return Status.SUCCESS

    def on_failure(self, error: HalError) -> Status:
        if error.kind != "comms_lost":      # the controller's own word: nothing gripped
            self.bb.set(PHASE, None)
        if error.kind == "missed_grab" and self.timing is not None:
            robot_fit(self.ctx).pick_missed(self.timing, self.ctx.now())
        self._log(error.kind, None)
        self.timing = None
        return super().on_failure(error)

    def _log(self, outcome: str, grip_x: object) -> None:
        """The pick as the cell timed it (a twin's fit reads it: tuning/twin.py): where the
        arm was and where it went, at what speed, how long it took and how it ended."""
        t = self.timing
        if t is None:
            return
        self.ctx.stats.emit(
            t.t0, "pick", dt=round(self.ctx.now() - t.t0, 4), outcome=outcome,
            x0=round(t.start[0], 1), y0=round(t.start[1], 1),
            grip_x=None if grip_x is None else round(float(grip_x), 1),  # type: ignore[arg-type]
            y=round(t.tool_y, 1), speed=t.speed_pct, belt_mm_s=round(t.belt_mm_s, 1),
            tracking=t.tracking, usable=t.usable, part=self.part.id if self.part else None)

    def terminate(self, new_status: Status) -> None:
        was_running = self.status is Status.RUNNING and self.job is not None and not self.job.done
        super().terminate(new_status)
        if new_status is Status.INVALID and was_running:
            # pre-empted (pause, stop) before the grip: the part is still on the belt
            self.bb.set(PHASE, None)
            self.ctx.queue.put_front(self.part)


class Place(PartJob):
    def start(self) -> Job:
        part = self.part
        spec = self.ctx.scenario.parts[part.type]
        place = spec.place
        # a symmetric part needs only its angle modulo its period: the shortest turn
        rz = -wrap_deg(part.angle_deg, spec.period_deg) if place.orient else 0.0
        self.bb.set(PHASE, "place")
        self.timing = self._timing("place", end=(place.x, place.y))
        return self.ctx.hal.robot.place(Pose(place.x, place.y, place.z, rz))

    def terminate(self, new_status: Status) -> None:
        super().terminate(new_status)
        if new_status is Status.INVALID and self.job is not None and self.job.ok \
                and self.status is Status.RUNNING:
            self.timing = None                    # cut short: not a move time
            self.on_success(self.job.result)      # pre-empted, but the part was placed

    def on_success(self, result: object) -> Status:
        if self.timing is not None:
            robot_fit(self.ctx).place_done(self.timing, self.ctx.now())
            t = self.timing
            assert t.end is not None
            self.ctx.stats.emit(t.t0, "place", dt=round(self.ctx.now() - t.t0, 4),
                                x0=round(t.start[0], 1), y0=round(t.start[1], 1),
                                x=t.end[0], y=t.end[1], speed=t.speed_pct)
            self.timing = None
        self.bb.set(PHASE, None)
        count_retrieved(self.ctx, self.part)
        return Status.SUCCESS

    def on_failure(self, error: HalError) -> Status:
        if error.kind != "comms_lost":      # e.g. a servo fault: the part is still held
            self.bb.set(PHASE, "held")
        return super().on_failure(error)


class Reconcile(PartJob):
    """After a lost reply (or a restart), ask the controller what the gripper holds and
    settle where the part the cell commanded really is:

    - the gripper holds it: ``held`` (the next step places it);
    - the pick's reply was lost and nothing is held: it was never gripped, so it is still
      on the belt: back to the front of the queue (too far by now, it is dropped there);
    - a place's reply was lost and the controller released it at the place pose: counted
      as retrieved; released anywhere else: counted as dropped (the world has it);
    - the gripper holds something no pick of ours gripped: ``UnknownPart``."""

    recovers = ("comms_lost",)      # a reply proves the link, not the arm's power
    READS = (*PartJob.READS, PHASE)

    def start(self) -> Job:
        self.feedback_message = "asking the robot what it holds"
        return self.ctx.hal.robot.held()

    def on_success(self, result: object) -> Status:
        held: Held = result                   # type: ignore[assignment]
        part = self.part
        phase = self.bb.get(PHASE)
        stats = self.ctx.stats
        if held.unknown or (held.part_id is not None
                            and (part is None or held.part_id != part.id)):
            what = "something" if held.part_id is None else f"part {held.part_id}"
            return self.on_failure(UnknownPart(
                f"the gripper holds {what}, which this run did not pick: remove it"))
        if held.part_id is not None:
            if phase != "held":
                stats.emit(self.ctx.now(), "reconciled", id=part.id, found="in the gripper",
                           phase=phase)
            self.bb.set(PHASE, "held")
            self.feedback_message = f"part {part.id} is in the gripper"
            return Status.SUCCESS
        if phase == "pick":
            self.ctx.queue.put_front(part)
            found = "on the belt (never gripped)"
        elif phase in ("held", "place") and held.last_placed == part.id:
            count_retrieved(self.ctx, part, reconciled=True)
            found = "placed (its reply was lost)"
        elif phase in ("held", "place"):
            stats.count("dropped")
            found = "dropped (let go away from the place pose)"
        else:
            found = None
        if found is not None:
            stats.emit(self.ctx.now(), "reconciled", id=part.id, found=found, phase=phase)
            self.feedback_message = f"part {part.id}: {found}"
        self.bb.set(PHASE, None)
        return Status.SUCCESS


class PhaseIs(Leaf):
    """Condition: the retriever's record of the part is ``phase`` (None: nothing pending)."""

    READS = (PHASE,)

    def __init__(self, name: str, ctx: Ctx, phase: str | None) -> None:
        super().__init__(name, ctx)
        self.phase = phase

    def update(self) -> Status:
        return Status.SUCCESS if self.bb.get(PHASE) == self.phase else Status.FAILURE


class Holding(Leaf):
    """Condition: the gripper holds a part (a place was cut short by a fault)."""

    def update(self) -> Status:
        return Status.SUCCESS if self.ctx.hal.robot.holding() else Status.FAILURE


class Recover(JobLeaf):
    """Servo time-out: run the controller's recovery program and re-enable power. Its
    success is the servo fault's recovery; if a link drop cuts its reply, the controller
    may have finished it anyway, and the next motion that succeeds is the recovery."""

    fault_key = RETRIEVE.ERROR
    WRITES = (RETRIEVE.ERROR,)

    def start(self) -> Job:
        self.ctx.stats.recovering(self.fault_key, "servo_timeout")
        return self.ctx.hal.robot.recover()


class MoveSafe(JobLeaf):
    fault_key = RETRIEVE.ERROR
    WRITES = (RETRIEVE.ERROR,)

    def start(self) -> Job:
        return self.ctx.hal.robot.move_safe()


class SetRobotSpeed(JobLeaf):
    def start(self) -> Job:
        return self.ctx.hal.robot.set_speed(self.ctx.scenario.retrieve.robot_speed_pct)


class FollowRobotSpeed(Leaf):
    """Apply a robot speed written to the blackboard (by the adjuster or the operator)."""

    READS = (SPEEDS.ROBOT,)

    def __init__(self, name: str, ctx: Ctx) -> None:
        super().__init__(name, ctx)
        self.applied: float | None = None

    def update(self) -> Status:
        pct = float(self.bb.get(SPEEDS.ROBOT))
        if pct != self.applied:
            self.ctx.hal.robot.set_speed(pct)
            self.applied = pct
        return Status.SUCCESS
